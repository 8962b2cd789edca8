"""The binary codec of commits and snapshots (``tracer.scene.codec``): exact round trips, raw
binary arrays, and refusal of anything malformed, truncated or corrupted."""

import dataclasses
import json
import struct
import zlib

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from tests.scene_states import assert_states_equal, small_state, spinning_animation
from tracer.errors import SceneError
from tracer.scene import codec
from tracer.scene import format as fmt
from tracer.scene import ops as so
from tracer.scene.model import make_mesh


def craft(header: dict | bytes, payload: bytes = b"") -> bytes:
    """Bytes in the documented layout, with a correct checksum, around any header."""
    text = (
        header if isinstance(header, bytes) else json.dumps(header, separators=(",", ":")).encode()
    )
    body = struct.pack("<I", len(text)) + text + b"\0" * (-(12 + len(text)) % 8) + payload
    return b"TLR1" + struct.pack("<I", zlib.crc32(body)) + body


def header_of(data: bytes) -> dict:
    (length,) = struct.unpack_from("<I", data, 8)
    return json.loads(data[12 : 12 + length])


def payload_of(data: bytes) -> bytes:
    (length,) = struct.unpack_from("<I", data, 8)
    return data[12 + length + (-(12 + length) % 8) :]


# --- round trips ------------------------------------------------------------------------------


def test_set_transform_commit_is_small_and_exact():
    commit = so.Commit(
        8, [so.SetTransform(node="cube", transform=fmt.Transform(translate=(0.1, -0.0, 1e-300)))]
    )
    data = codec.encode_commit(commit)
    assert len(data) < 160
    decoded = codec.decode_commit(data)
    assert decoded == commit
    assert str(decoded.ops[0].transform.translate[1]) == "-0.0"


def test_arrays_travel_as_raw_bytes():
    """A 10,000-vertex update is the vertex bytes plus a small header, and decodes bit for bit
    into a read-only array that does not alias the input."""
    vertices = np.random.default_rng(3).normal(size=(10_000, 3))
    commit = so.Commit(2, [so.UpdateVertices(mesh="cloth", vertices=vertices)])
    data = bytearray(codec.encode_commit(commit))
    assert 10_000 * 24 < len(data) < 10_000 * 24 + 200
    assert header_of(data)["arrays"] == [["<f8", [10_000, 3]]]
    assert payload_of(data) == vertices.astype("<f8").tobytes()
    decoded = codec.decode_commit(data)
    assert decoded == commit
    data[-8:] = b"\xff" * 8
    assert decoded.ops[0].vertices[-1, -1] == vertices[-1, -1]
    assert not decoded.ops[0].vertices.flags.writeable


def test_snapshot_round_trip_is_exact():
    state = small_state(version=12, animation=spinning_animation())
    state = so.apply_ops(
        state,
        [
            so.AddMesh(mesh="odd", vertices=[[-0.0, 5e-324, 1e308]] * 3, faces=[[0, 1, 2]]),
            so.AddMesh(
                mesh="smooth",
                vertices=[[0, 0, 0], [1, 0, 0], [0, 1, 0]],
                faces=[[0, 1, 2]],
                uvs=[[0, 0], [1, 0], [0, 1]],
                normals=[[0.1, 0.2, 1.0], [0.0, 0.0, 3.0], [-0.3, 0.1, 1.0]],
            ),
            so.SetTransform(node=1, transform=fmt.Transform(rotate=(10.0, 20.0, 30.0))),
            so.SetSky(radiance=(0.0, 0.5, 1e-9)),
        ],
    )
    decoded = codec.decode_state(codec.encode_state(state))
    assert_states_equal(state, decoded)
    assert not decoded.nodes[1].transform.flags.writeable
    assert not decoded.meshes["odd"].vertices.flags.writeable
    assert decoded.meshes["smooth"].normals is not None and decoded.meshes["odd"].normals is None


@pytest.mark.parametrize(
    "change",
    [
        {"nodes": {}, "animation": None},
        {"meshes": {}, "nodes": {}, "materials": {}},
        {"animation": dataclasses.replace(spinning_animation(), camera=())},
        {"animation": dataclasses.replace(spinning_animation(), nodes={})},
    ],
    ids=["no-nodes", "empty", "no-camera-track", "camera-track-only"],
)
def test_snapshot_round_trip_of_sparse_states(change):
    state = dataclasses.replace(small_state(version=1), **change)
    assert_states_equal(state, codec.decode_state(codec.encode_state(state)))


finite = st.floats(allow_nan=False, allow_infinity=False)
small = st.floats(-1e3, 1e3, allow_nan=False)
vec3 = st.tuples(small, small, small)
names = st.text(min_size=1, max_size=12)
node_refs = st.integers(0, 2**63 - 1) | names
vertex_arrays = st.integers(1, 20).flatmap(
    lambda n: hnp.arrays(np.float64, (n, 3), elements=finite)
)
face_arrays = st.integers(1, 20).flatmap(
    lambda n: hnp.arrays(np.int64, (n, 3), elements=st.integers(0, 2**63 - 1))
)
transforms = st.one_of(
    st.builds(fmt.Transform, translate=vec3, rotate=vec3, scale=st.floats(0.1, 10)),
    st.builds(
        lambda t: fmt.Transform(matrix=((1, 0, 0, t), (0, 2, 0, 0), (0, 0, 3, 0), (0, 0, 0, 1))),
        small,
    ),
)
materials = st.builds(
    fmt.DiffuseMaterial,
    reflectance=st.tuples(*[st.floats(0, 1)] * 3),
    emission=st.tuples(*[st.floats(0, 1e6)] * 3),
    two_sided=st.booleans(),
)
radiance = st.tuples(*[st.floats(0, 1e6)] * 3)
kinds = st.sampled_from(["static", "rigid", "deformable", "dynamic"])
any_op = st.one_of(
    st.builds(so.SetTransform, node=node_refs, transform=transforms),
    st.builds(so.SetMaterial, name=names, material=materials),
    st.builds(so.AssignMaterial, node=node_refs, material=names),
    st.builds(so.SetLight, material=names, emission=radiance),
    st.builds(so.SetCamera, camera=st.builds(fmt.Camera, position=st.just((1.0, 2.0, 3.0)),
                                             vfov_deg=st.floats(1, 179), width=st.integers(1, 99))),
    st.builds(so.SetSky, radiance=radiance),
    st.builds(so.SetRender, render=st.builds(fmt.RenderSettings, seed=st.integers(0, 2**63 - 1))),
    st.builds(so.AddMesh, mesh=names, vertices=vertex_arrays, faces=face_arrays),
    st.builds(so.RemoveMesh, mesh=names),
    st.builds(so.UpdateVertices, mesh=names, vertices=vertex_arrays),
    st.builds(so.ReplaceMesh, mesh=names, vertices=vertex_arrays, faces=face_arrays),
    st.builds(so.AddNode, id=st.none() | st.integers(0, 2**63 - 1), name=st.text(max_size=5),
              parent=st.none() | node_refs, transform=transforms, kind=kinds,
              mesh=st.none() | names, material=st.none() | names),
    st.builds(so.RemoveNode, node=node_refs),
    st.builds(so.SetKind, node=node_refs, kind=kinds),
)  # fmt: skip


@settings(max_examples=150, derandomize=True)
@given(st.integers(-(2**63), 2**63), st.lists(any_op, max_size=6))
def test_commit_round_trip_over_op_sequences(version, ops):
    """Every op kind, any values the models accept: decode(encode(c)) == c, arrays bit for bit,
    and encoding is deterministic."""
    commit = so.Commit(version, ops)
    data = codec.encode_commit(commit)
    decoded = codec.decode_commit(data)
    assert decoded == commit
    assert codec.encode_commit(decoded) == data


# --- malformed input --------------------------------------------------------------------------


def sample_commit() -> bytes:
    return codec.encode_commit(
        so.Commit(3, [so.AddMesh(mesh="t", vertices=[[0, 0, 0]] * 3, faces=[[0, 1, 2]])])
    )


def test_every_truncation_is_refused():
    data = sample_commit()
    for end in range(len(data)):
        with pytest.raises(SceneError, match="cannot decode commit"):
            codec.decode_commit(data[:end])
    snapshot = codec.encode_state(small_state())
    for end in range(0, len(snapshot), 7):
        with pytest.raises(SceneError, match="cannot decode snapshot"):
            codec.decode_state(snapshot[:end])


@settings(max_examples=200, derandomize=True)
@given(st.data())
def test_corrupted_bytes_are_refused(data):
    """Any changed byte (magic, checksum, length, header, padding or arrays) is refused."""
    blob = bytearray(sample_commit())
    index = data.draw(st.integers(0, len(blob) - 1))
    blob[index] ^= data.draw(st.integers(1, 255))
    with pytest.raises(SceneError, match="cannot decode commit: "):
        codec.decode_commit(bytes(blob))


@pytest.mark.parametrize(
    "blob, message",
    [
        (b"", "too short"),
        (b"XXXX" + bytes(8), "wrong magic"),
        (craft(b"{not json"), r"the header is not JSON \(Invalid JSON: key must be a string"),
        (craft(b"[" * 100_000), "the header is not JSON"),
        (craft({"kind": "state"}), "header: kind: Input should be 'commit'"),
        (craft({"kind": "commit", "version": 1, "ops": [], "arrays": [], "x": 1}), "unknown key"),
        (craft({"kind": "commit", "version": "1", "ops": [], "arrays": []}), "header: version"),
        (craft({"kind": "commit", "version": 1, "ops": [], "arrays": [["|O", [1]]]}), "arrays.0.0"),
        (craft({"kind": "commit", "version": 1, "ops": [], "arrays": [["<f8", [10**30]]]}),
         "runs past the end"),
        (craft({"kind": "commit", "version": 1, "ops": [], "arrays": []}, b"\0" * 8),
         "8 unexpected bytes after the arrays"),
        (craft({"kind": "commit", "version": 1, "ops": [{"op": "set_sky", "radiance": [1, 1]}],
                "arrays": []}), r"op 0 \(set_sky\): radiance.2: Field required"),
        (craft(b'{"kind":"commit","version":1,"ops":[{"op":"set_sky","radiance":[NaN,0,0]}],'
               b'"arrays":[]}'), r"op 0 \(set_sky\): radiance.0: Input should be a finite number"),
        (craft({"kind": "commit", "version": 1,
                "ops": [{"op": "update_vertices", "mesh": "m", "vertices": {"$array": 1}}],
                "arrays": [["<f8", [1, 3]]]}, b"\0" * 24), "array reference 1 does not exist"),
        (craft({"kind": "commit", "version": 1,
                "ops": [{"op": "update_vertices", "mesh": "m", "vertices": {"$array": 0}}],
                "arrays": [["<f8", [1, 2]]]}, b"\0" * 16), r"shape \(N, 3\) with N >= 1"),
    ],
    ids=lambda value: value if isinstance(value, str) else None,
)  # fmt: skip
def test_malformed_commits_are_refused(blob, message):
    """Well checksummed but malformed: refused with a one-line reason."""
    with pytest.raises(SceneError, match=message) as info:
        codec.decode_commit(blob)
    assert str(info.value).startswith("cannot decode commit: ") and "\n" not in str(info.value)


def tampered_snapshot(edit) -> bytes:
    """The small state's snapshot with its header changed by ``edit(header)``."""
    data = codec.encode_state(small_state(animation=spinning_animation()))
    header = header_of(data)
    edit(header)
    return craft(header, payload_of(data))


def test_the_snapshot_helpers_reproduce_the_encoding():
    data = codec.encode_state(small_state(animation=spinning_animation()))
    assert tampered_snapshot(lambda header: None) == data


@pytest.mark.parametrize(
    "edit, message",
    [
        (lambda h: h["nodes"][1].__setitem__(2, 77), "node 1 .*: parent 77 does not exist"),
        (lambda h: h["nodes"][0].__setitem__(2, 3), "parent chain loops back"),
        (lambda h: h["nodes"][1].__setitem__(0, 0), "node id 0 appears twice"),
        (lambda h: h["nodes"][1].__setitem__(3, "soft"), "nodes.1.3: Input should be"),
        (lambda h: h["nodes"][1].__setitem__(4, "cone"), "mesh 'cone' does not exist"),
        (lambda h: h["nodes"].pop(), r"expected \(4, 4, 4\)"),
        (lambda h: h["meshes"][0].__setitem__(1, h["meshes"][0][2]), "has dtype int64"),
        (lambda h: h["meshes"].append(h["meshes"][0]), "mesh 'quad' appears twice"),
        (lambda h: h["materials"].append(h["materials"][0]), "material name appears twice"),
        (lambda h: h["materials"][0][1].__setitem__("reflectance", [2, 0, 0]), "reflectance.0"),
        (lambda h: h["camera"].__setitem__("vfov_deg", 180), "camera.vfov_deg"),
        (lambda h: h["animation"].__setitem__("fps", 0.0), "fps must be a positive number"),
        (lambda h: h["animation"]["nodes"][0].__setitem__(0, 9), "node 9: the node does not exist"),
        (lambda h: h["animation"]["nodes"].append([2, 0]), "node 2 has two animation tracks"),
        (lambda h: h["animation"].__setitem__("camera", 0), r"expected \(None, 11\)"),
        (lambda h: h.__setitem__("version", 1.5), "version"),
    ],
)  # fmt: skip
def test_inconsistent_snapshots_are_refused(edit, message):
    with pytest.raises(SceneError, match="cannot decode snapshot: .*" + message):
        codec.decode_state(tampered_snapshot(edit))


def test_kinds_and_types_do_not_mix():
    with pytest.raises(SceneError, match="kind: Input should be 'state'"):
        codec.decode_state(sample_commit())
    with pytest.raises(SceneError, match="kind: Input should be 'commit'"):
        codec.decode_commit(codec.encode_state(small_state()))
    with pytest.raises(SceneError, match="expected bytes, not str"):
        codec.decode_commit("TLR1")


def test_unsorted_key_times_are_refused():
    state = small_state(animation=spinning_animation())
    keys = state.animation.nodes[2]
    backwards = dataclasses.replace(state.animation, nodes={2: keys[::-1]})
    data = codec.encode_state(dataclasses.replace(state, animation=backwards))
    with pytest.raises(SceneError, match="key times must be finite and never decrease"):
        codec.decode_state(data)


def test_shared_mesh_objects_survive_as_equal_meshes():
    mesh = make_mesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])
    state = dataclasses.replace(
        small_state(), meshes={**small_state().meshes, "a": mesh, "b": mesh}
    )
    assert_states_equal(state, codec.decode_state(codec.encode_state(state)))


json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False) | st.text(max_size=5),
    lambda inner: (
        st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=6), inner, max_size=4)
    ),
    max_leaves=30,
)
op_like = st.fixed_dictionaries(
    {"op": st.sampled_from(sorted(so.OP_KINDS))},
    optional={
        key: json_values | st.just({"$array": 0})
        for key in ("node", "mesh", "name", "vertices", "faces", "transform", "kind", "id")
    },
)


@settings(max_examples=200, derandomize=True)
@given(
    st.fixed_dictionaries(
        {"kind": st.just("commit") | json_values, "version": st.integers() | json_values},
        optional={"ops": st.lists(op_like | json_values, max_size=3), "arrays": json_values},
    ),
    st.binary(max_size=48),
)
def test_arbitrary_headers_never_crash(header, payload):
    """Checksummed but arbitrary headers and payloads: a Commit or a SceneError, nothing else."""
    try:
        assert isinstance(codec.decode_commit(craft(header, payload)), so.Commit)
    except SceneError as error:
        assert str(error).startswith("cannot decode commit: ")


@settings(max_examples=200, derandomize=True)
@given(st.data())
def test_arbitrary_snapshot_fields_never_crash(data):
    """One field of a real snapshot header (or of one of its rows) replaced by any JSON value:
    a consistent state or a SceneError, nothing else."""

    def edit(header):
        key = data.draw(st.sampled_from(sorted(header)))
        target = header
        if isinstance(header[key], list) and header[key] and data.draw(st.booleans()):
            target, key = header[key], data.draw(st.integers(0, len(header[key]) - 1))
        target[key] = data.draw(json_values)

    try:
        codec.decode_state(tampered_snapshot(edit))
    except SceneError as error:
        assert str(error).startswith("cannot decode snapshot: ")

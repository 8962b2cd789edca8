"""A replica that applies commits renders exactly what a fresh compile of the same state
renders, whatever the sequence of edits; bad commits change nothing; refits stay valid."""

import numpy as np
import pytest
import trimesh
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cluster.scene_graph import SceneGraph
from tests.scene_states import node, translation
from tracer.compiled.scene import compile_scene
from tracer.errors import SceneError
from tracer.geometry import bvh
from tracer.geometry.raycast import closest_hits
from tracer.render import render_image
from tracer.scene import format as fmt
from tracer.scene.codec import encode_commit
from tracer.scene.model import SceneState, Sky, make_mesh
from tracer.scene.ops import CommitGap
from worker.replica import SceneReplica

CAMERA = fmt.Camera(position=(0.0, 3.0, 9.0), look_at=(0.0, 0.5, 0.0), width=32, height=24)
SETTINGS = fmt.RenderSettings(spp=2, max_depth=4, seed=3)


def blob(subdivisions: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    mesh = trimesh.creation.icosphere(subdivisions=subdivisions, radius=0.7)
    rng = np.random.default_rng(seed)
    return mesh.vertices * rng.uniform(0.9, 1.1, (len(mesh.vertices), 1)), mesh.faces


def studio() -> SceneState:
    """Every kind of node: a static floor and lamp, two rigid instances of one box (instancing,
    one parented), a deformable blob."""
    box = trimesh.creation.box(extents=(1, 1, 1))
    meshes = {
        "floor": make_mesh(
            [[-4, 0, -4], [-4, 0, 4], [4, 0, 4], [4, 0, -4]], [[0, 1, 2], [0, 2, 3]]
        ),
        "box": make_mesh(box.vertices, box.faces),
        "blob": make_mesh(*blob(1)),
    }
    materials = {
        "white": fmt.DiffuseMaterial(),
        "red": fmt.DiffuseMaterial(reflectance=(0.8, 0.2, 0.1)),
        "lamp": fmt.DiffuseMaterial(reflectance=(0, 0, 0), emission=(9, 8, 7), two_sided=False),
    }
    lamp = np.array([[1, 0, 0, 0], [0, -1, 0, 4], [0, 0, -1, 0], [0, 0, 0, 1.0]])
    nodes = [
        node(0, "floor", mesh="floor", material="white"),
        node(1, "lamp", None, lamp, "static", "floor", "lamp"),
        node(2, "box-a", None, translation(-1.5, 0.5, 0), "rigid", "box", "red"),
        node(3, "box-b", 2, translation(0, 1.0, 0), "rigid", "box", "white"),
        node(4, "blob", None, translation(1.5, 0.7, 0), "deformable", "blob", "white"),
    ]
    return SceneState(
        version=0,
        meshes=meshes,
        materials=materials,
        nodes={n.id: n for n in nodes},
        camera=CAMERA,
        render=SETTINGS,
        sky=Sky((0.05, 0.05, 0.08)),
    )


def image(scene) -> np.ndarray:
    return render_image(scene, settings=SETTINGS, threads=2)[0]


vec = st.tuples(*[st.floats(-2.0, 2.0, allow_nan=False)] * 3)
ops = st.one_of(
    st.builds(
        lambda n, t, r: {
            "op": "set_transform",
            "node": n,
            "transform": {"translate": t, "rotate": [r, 2 * r, 0]},
        },
        st.sampled_from(["box-a", "box-b", "blob"]),
        vec,
        st.floats(-90, 90),
    ),
    st.builds(
        lambda seed, k, shift: {
            "op": "update_vertices",
            "mesh": "blob",
            "vertices": blob(1, seed)[0] * k + np.array(shift) * 0.5,
        },
        st.integers(0, 1000),
        st.floats(0.5, 1.5),
        vec,
    ),
    st.builds(
        lambda sub, seed: dict(
            zip(
                ("op", "mesh", "vertices", "faces"),
                ("replace_mesh", "blob", *blob(sub, seed)),
                strict=True,
            )
        ),
        st.integers(0, 2),
        st.integers(0, 1000),
    ),
    st.builds(
        lambda e: {"op": "set_light", "material": "lamp", "emission": [e, e, e]},
        st.floats(0.0, 20.0),
    ),
    st.builds(
        lambda r: {"op": "set_material", "name": "red", "material": {"reflectance": [r, 0.2, 0.1]}},
        st.floats(0, 1),
    ),
    st.builds(
        lambda n, m: {"op": "assign_material", "node": n, "material": m},
        st.sampled_from(["box-a", "blob", "floor"]),
        st.sampled_from(["white", "red"]),
    ),
    st.builds(
        lambda n, k: {"op": "set_kind", "node": n, "kind": k},
        st.sampled_from(["box-a", "box-b", "blob", "floor"]),
        st.sampled_from(["static", "rigid", "deformable", "dynamic"]),
    ),
    st.builds(
        lambda t: {
            "op": "add_node",
            "name": "extra",
            "kind": "rigid",
            "mesh": "box",
            "material": "red",
            "transform": {"translate": t},
        },
        vec,
    ),
    st.just({"op": "remove_node", "node": "box-b"}),
    st.builds(
        lambda x: {
            "op": "set_camera",
            "camera": {**CAMERA.model_dump(), "position": [x, 3.0, 9.0]},
        },
        st.floats(-1, 1),
    ),
)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(commits=st.lists(st.lists(ops, min_size=1, max_size=3), min_size=1, max_size=5))
def test_replica_renders_like_a_fresh_compile(commits):
    """After any sequence of commits (each applied to the replica incrementally, through the
    byte codec), every version renders bit-identically to compiling that state from scratch."""
    graph = SceneGraph(studio())
    replica = SceneReplica(graph.snapshot())
    for op_list in commits:
        try:
            commit = graph.commit(op_list)
        except SceneError:
            continue  # e.g. removing box-b twice: refused by the graph, nothing to replay
        replica.apply([encode_commit(commit)])
        assert replica.version == graph.version
        fresh = compile_scene(graph.state)
        assert np.array_equal(image(replica.current), image(fresh))


def test_a_rejected_commit_changes_nothing():
    graph = SceneGraph(studio())
    replica = SceneReplica(graph.snapshot())
    before = image(replica.current)
    good = graph.commit([{"op": "set_light", "material": "lamp", "emission": [1, 1, 1]}])
    bad = type(good)(good.version + 1, good.ops + good.ops[:0])
    replica.apply([good])
    poisoned = graph.commit([{"op": "remove_node", "node": "box-b"}])
    poisoned = type(poisoned)(poisoned.version, ({"op": "remove_node", "node": "nope"},))
    with pytest.raises(SceneError):
        from tracer.scene.ops import parse_ops

        replica.apply(
            [type(bad)(poisoned.version, parse_ops([{"op": "remove_mesh", "mesh": "box"}]))]
        )
    assert replica.version == good.version
    assert not np.array_equal(image(replica.current), before)  # the good commit did apply


def test_commits_are_idempotent_and_gaps_are_refused():
    graph = SceneGraph(studio())
    replica = SceneReplica(graph.snapshot())
    first = graph.commit(
        [{"op": "set_transform", "node": "box-a", "transform": {"translate": [0, 1, 0]}}]
    )
    second = graph.commit(
        [{"op": "set_transform", "node": "box-a", "transform": {"translate": [0, 2, 0]}}]
    )
    third = graph.commit([{"op": "set_sky", "radiance": [0.2, 0.2, 0.2]}])
    with pytest.raises(CommitGap):
        replica.apply([first, third])
    assert replica.version == first.version  # the good prefix applied, nothing else
    replica.apply([first, second, second, third])
    assert replica.version == third.version
    assert np.array_equal(image(replica.current), image(compile_scene(graph.state)))


def test_a_frame_in_flight_keeps_its_version():
    """The compiled scene of a version is immutable: rendering it after newer commits gives the
    same pixels as before them."""
    graph = SceneGraph(studio())
    replica = SceneReplica(graph.snapshot())
    scheduled = replica.current
    before = image(scheduled)
    replica.apply(
        [graph.commit([{"op": "update_vertices", "mesh": "blob", "vertices": blob(1, 7)[0]}])]
    )
    replica.apply(
        [
            graph.commit(
                [{"op": "set_transform", "node": "box-a", "transform": {"translate": [1, 1, 1]}}]
            )
        ]
    )
    assert replica.at(replica.version - 1) is not scheduled  # only KEEP_VERSIONS are held
    assert np.array_equal(image(scheduled), before)
    assert not np.array_equal(image(replica.current), before)


def test_rigid_motion_reuses_every_mesh_and_pool():
    """Moving a rigid node rebuilds the top level only: mesh BVHs and pools are shared."""
    graph = SceneGraph(studio())
    replica = SceneReplica(graph.snapshot())
    old = replica.current
    replica.apply(
        [
            graph.commit(
                [{"op": "set_transform", "node": "box-a", "transform": {"translate": [0, 3, 0]}}]
            )
        ]
    )
    new = replica.current
    assert all(new.meshes[k] is old.meshes[k] for k in old.meshes)
    assert new.pools[0] is old.pools[0] and new.pools[1] is old.pools[1]


@pytest.mark.parametrize("seed", range(6))
def test_refitted_bounds_contain_their_geometry(seed):
    """update_vertices refits the blob's tree: every box still contains its children and its
    triangles, and hits agree with a tree built from scratch."""
    graph = SceneGraph(studio())
    replica = SceneReplica(graph.snapshot())
    old = replica.current.meshes["blob"]
    vertices = blob(1, seed)[0] * np.random.default_rng(seed).uniform(0.5, 1.5, (1, 3))
    replica.apply([graph.commit([{"op": "update_vertices", "mesh": "blob", "vertices": vertices}])])
    refit = replica.current.meshes["blob"]
    assert refit.bvh.node_child is old.bvh.node_child  # same topology: refitted, not rebuilt
    t = refit.bvh
    boxes = bvh.slot_boxes(t.node_bounds)
    for n in range(t.node_child.shape[0]):
        for side in range(bvh.WIDTH):
            c = t.node_child[n, side]
            box = boxes[n, side]
            if c >= 0:
                kids = boxes[c]
                assert (box[0] <= kids[:, 0]).all() and (kids[:, 1] <= box[1]).all()
            else:
                first, count = bvh.decode_leaf(c)
                if count:
                    tri = t.tri_verts[first : first + count].reshape(-1, 3)
                    assert (box[0] <= tri.min(axis=0)).all() and (tri.max(axis=0) <= box[1]).all()
    rng = np.random.default_rng(seed)
    o = rng.uniform(-2, 2, (2000, 3))
    d = rng.normal(size=(2000, 3))
    rebuilt = bvh.to_traversal(bvh.build(t.tri_verts), t.tri_verts)
    a = closest_hits(t, o, d)
    b = closest_hits(rebuilt, o, d)
    assert np.array_equal(a.t, b.t)
    assert np.array_equal(a.prim, np.where(b.prim >= 0, t.tri_prim[b.prim], -1))


def test_query_reports_node_triangle_point_and_material():
    replica = SceneReplica(studio())
    hits = replica.query([[-1.5, 3.5, 0.1], [1.5, 3.5, 0.0], [9.0, 9.0, 9.0]],
                         [[0, -1, 0], [0, -1, 0], [1, 0, 0]])  # fmt: skip
    names = [replica.state.nodes[n].name if n >= 0 else None for n in hits.node]
    assert names == ["box-b", "blob", None]
    assert hits.material == ["white", "white", None]
    np.testing.assert_allclose(hits.point[0], [-1.5, 2.0, 0.1], atol=1e-9)
    np.testing.assert_allclose(hits.normal[0], [0, 1, 0], atol=1e-12)
    assert hits.t[2] == np.inf

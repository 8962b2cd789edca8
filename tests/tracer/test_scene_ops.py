"""Scene operations (``tracer.scene.ops``): what each does, what each refuses and why, structural
sharing with the previous state, atomicity, and commits."""

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tests.scene_states import QUAD, TRIANGLE, small_state, spinning_animation, translation
from tracer.errors import SceneError
from tracer.scene import format as fmt
from tracer.scene import ops as so
from tracer.scene.checks import check_state


def apply(state, *ops):
    return so.apply_ops(state, so.parse_ops(ops))


def assert_shares_all_but(old, new, nodes=(), meshes=(), materials=()):
    """Every node, mesh and material of ``old`` that is not named is the same object in ``new``."""
    for table, changed in (("nodes", nodes), ("meshes", meshes), ("materials", materials)):
        old_table, new_table = getattr(old, table), getattr(new, table)
        for key, value in old_table.items():
            if key not in changed:
                assert new_table[key] is value, f"{table}[{key!r}] was copied"


# --- each op does what it says, and touches nothing else --------------------------------------


def test_set_transform_replaces_the_local_transform():
    old = small_state()
    new = apply(old, {"op": "set_transform", "node": "cube", "transform": {"translate": [0, 3, 0]}})
    np.testing.assert_array_equal(new.nodes[2].transform, translation(0, 3, 0))
    assert not new.nodes[2].transform.flags.writeable
    assert_shares_all_but(old, new, nodes={2})
    np.testing.assert_array_equal(old.nodes[2].transform, translation(2, 0, 0))


def test_world_transforms_compose_through_parents():
    """handle (y=1) under cube (x=2) under room: moving the room moves the handle, and the
    handle node itself is untouched (shared)."""
    old = small_state()
    np.testing.assert_array_equal(old.world_transform(3), translation(2, 1, 0))
    new = apply(old, {"op": "set_transform", "node": 0, "transform": {"translate": [0, 0, -7]}})
    assert new.nodes[3] is old.nodes[3]
    np.testing.assert_array_equal(new.world_transform(3), translation(2, 1, -7))
    rotated = apply(new, {"op": "set_transform", "node": 2, "transform": {"rotate": [0, 0, 90]}})
    np.testing.assert_allclose(
        rotated.world_transform(3) @ [0, 0, 0, 1], [-1, 0, -7, 1], atol=1e-15
    )


def test_set_material_adds_and_replaces():
    old = small_state()
    blue = {"reflectance": [0.1, 0.1, 0.9]}
    new = apply(
        old,
        {"op": "set_material", "name": "blue", "material": blue},
        {"op": "set_material", "name": "red", "material": {"two_sided": False}},
    )
    assert new.materials["blue"] == fmt.DiffuseMaterial(reflectance=(0.1, 0.1, 0.9))
    assert new.materials["red"].two_sided is False
    assert set(old.materials) == {"white", "red", "light"}
    assert_shares_all_but(old, new, materials={"red"})


def test_assign_material_and_set_light():
    old = small_state()
    new = apply(
        old,
        {"op": "assign_material", "node": "floor", "material": "red"},
        {"op": "set_light", "material": "light", "emission": [2, 2, 1.5]},
    )
    assert new.nodes[1].material == "red" and old.nodes[1].material == "white"
    assert new.materials["light"].emission == (2.0, 2.0, 1.5)
    assert new.materials["light"].reflectance == old.materials["light"].reflectance
    assert_shares_all_but(old, new, nodes={1}, materials={"light"})


def test_camera_sky_and_render():
    old = small_state()
    new = apply(
        old,
        {"op": "set_camera", "camera": {"position": [1, 1, 1], "width": 8, "height": 8}},
        {"op": "set_sky", "radiance": [1, 0, 0]},
        {"op": "set_render", "render": {"spp": 16, "seed": 9}},
    )
    assert new.camera.position == (1.0, 1.0, 1.0) and new.camera.width == 8
    assert new.sky.radiance == (1.0, 0.0, 0.0)
    assert (new.render.spp, new.render.seed) == (16, 9)
    assert new.nodes is old.nodes and new.meshes is old.meshes and new.materials is old.materials


def test_mesh_ops():
    old = small_state()
    moved = np.array(QUAD[0]) + 1.0
    new = apply(
        old,
        {"op": "add_mesh", "mesh": "tri2", "vertices": np.array(TRIANGLE[0]), "faces": TRIANGLE[1]},
        {"op": "update_vertices", "mesh": "quad", "vertices": moved},
        {"op": "replace_mesh", "mesh": "tri", "vertices": QUAD[0], "faces": QUAD[1]},
    )
    assert new.meshes["tri2"].triangles == 1
    np.testing.assert_array_equal(new.meshes["quad"].vertices, moved)
    assert new.meshes["quad"].faces is old.meshes["quad"].faces, "update_vertices shares faces"
    assert new.meshes["tri"].triangles == 2 and old.meshes["tri"].triangles == 1
    assert not new.meshes["tri2"].vertices.flags.writeable
    assert_shares_all_but(old, new, meshes={"quad", "tri"})
    gone = apply(new, {"op": "remove_mesh", "mesh": "tri2"})
    assert "tri2" not in gone.meshes and "tri2" in new.meshes


def test_mesh_normals_through_the_ops():
    """Normals given with a mesh are normalised; a smooth mesh whose vertices move without new
    normals gets area-weighted ones from its moved triangles, given ones replace them, and a
    flat mesh stays flat; bad normals are refused with the reason."""
    leaning = [[0.0, 0.0, 2.0], [0.0, 0.0, 1.0], [1.0, 0.0, 1.0], [0.0, 1.0, 1.0]]
    state = apply(
        small_state(),
        {"op": "add_mesh", "mesh": "q", "vertices": QUAD[0], "faces": QUAD[1], "normals": leaning},
    )
    normals = state.meshes["q"].normals
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, rtol=0, atol=1e-15)
    np.testing.assert_array_equal(normals[0], [0.0, 0.0, 1.0])
    assert not normals.flags.writeable
    # Fold the quad along its diagonal: each vertex's normal becomes its faces' mean.
    folded = np.array(QUAD[0], dtype=np.float64)
    folded[2, 2] += 1.0
    moved = apply(state, {"op": "update_vertices", "mesh": "q", "vertices": folded}).meshes["q"]
    v, f = moved.vertices, moved.faces
    face_normals = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    for vertex in range(4):
        around = face_normals[(f == vertex).any(axis=1)].sum(axis=0)
        np.testing.assert_allclose(moved.normals[vertex], around / np.linalg.norm(around))
    given = apply(
        state, {"op": "update_vertices", "mesh": "q", "vertices": folded, "normals": leaning}
    ).meshes["q"]
    np.testing.assert_array_equal(given.normals, normals)
    flat = apply(state, {"op": "update_vertices", "mesh": "quad", "vertices": QUAD[0]})
    assert flat.meshes["quad"].normals is None
    for bad, message in (
        ([[0.0, 0.0, 0.0]] * 4, "zero length"),
        ([[0.0, 0.0, 1.0]] * 3, r"one \(x, y, z\) vector per vertex"),
        ([[np.nan, 0.0, 1.0]] * 4, "finite"),
    ):
        with pytest.raises(SceneError, match=message):
            apply(state, {"op": "replace_mesh", "mesh": "q", "vertices": QUAD[0],
                          "faces": QUAD[1], "normals": bad})  # fmt: skip


def test_add_node_defaults_and_explicit_id():
    old = small_state()
    new = apply(
        old,
        {"op": "add_node", "name": "group", "kind": "static"},
        {
            "op": "add_node",
            "name": "leaf",
            "parent": "group",
            "kind": "deformable",
            "mesh": "tri",
            "material": "white",
            "transform": {"scale": 2},
        },
        {"op": "add_node", "id": 100, "name": "far", "parent": 5, "kind": "rigid"},
        {"op": "add_node", "name": "after", "kind": "static"},
    )
    assert [new.nodes[i].name for i in (5, 6, 100, 101)] == ["group", "leaf", "far", "after"]
    leaf = new.nodes[6]
    assert (leaf.parent, leaf.kind, leaf.mesh, leaf.material) == (5, "deformable", "tri", "white")
    np.testing.assert_array_equal(leaf.transform, np.diag([2.0, 2.0, 2.0, 1.0]))
    np.testing.assert_array_equal(new.nodes[5].transform, np.eye(4))
    assert new.nodes[100].parent == 5
    assert_shares_all_but(old, new)
    check_state(new)


def test_add_node_to_an_empty_scene_gets_id_zero():
    empty = dataclasses.replace(small_state(), nodes={})
    new = apply(empty, {"op": "add_node", "name": "first", "kind": "static"})
    assert list(new.nodes) == [0]


def test_remove_node_removes_its_subtree_and_animation_tracks():
    old = small_state(animation=spinning_animation())
    new = apply(old, {"op": "remove_node", "node": "room"})
    assert list(new.nodes) == [4]
    assert new.nodes[4] is old.nodes[4]
    assert new.animation.nodes == {} and new.animation.camera == old.animation.camera
    assert len(old.nodes) == 5 and 2 in old.animation.nodes
    leaf_only = apply(old, {"op": "remove_node", "node": 3})
    assert sorted(leaf_only.nodes) == [0, 1, 2, 4]
    assert leaf_only.animation is old.animation, "no track removed: the animation is shared"
    check_state(new)
    check_state(leaf_only)


def test_set_kind():
    old = small_state()
    new = apply(old, {"op": "set_kind", "node": "floor", "kind": "dynamic"})
    assert new.nodes[1].kind == "dynamic" and old.nodes[1].kind == "static"
    assert_shares_all_but(old, new, nodes={1})


def test_a_state_without_changes_shares_its_tables():
    old = small_state()
    new = so.apply_ops(old, ())
    assert new.nodes is old.nodes and new.meshes is old.meshes and new.version == old.version


def test_ops_see_the_state_left_by_the_previous_ones():
    """A node added by op 0 is found by name in op 1; a mesh removed by op 1 is gone for op 2."""
    state = apply(
        small_state(),
        {"op": "add_node", "name": "new", "kind": "rigid", "mesh": "tri", "material": "red"},
        {"op": "set_transform", "node": "new", "transform": {"translate": [0, 0, 1]}},
    )
    np.testing.assert_array_equal(state.nodes[5].transform, translation(0, 0, 1))
    with pytest.raises(SceneError, match=r"op 2 \(update_vertices\): mesh 'x' does not exist"):
        apply(
            state,
            {"op": "add_mesh", "mesh": "x", "vertices": TRIANGLE[0], "faces": TRIANGLE[1]},
            {"op": "remove_mesh", "mesh": "x"},
            {"op": "update_vertices", "mesh": "x", "vertices": TRIANGLE[0]},
        )


def test_apply_ops_keeps_the_version():
    state = small_state(version=7)
    assert apply(state, {"op": "set_sky", "radiance": [0, 0, 0]}).version == 7


# --- refusals ----------------------------------------------------------------------------------

GOOD_TRANSFORM = {"translate": [0, 0, 0]}
REFUSED = [
    # references
    ({"op": "set_transform", "node": 42, "transform": GOOD_TRANSFORM}, "node 42 does not exist"),
    ({"op": "set_transform", "node": "nobody", "transform": {}}, "no node is named 'nobody'"),
    ({"op": "set_kind", "node": "floor", "kind": "wobbly"}, r"op 1 \(set_kind\): kind: Input"),
    ({"op": "assign_material", "node": 1, "material": "gold"}, "material 'gold' does not exist"),
    ({"op": "assign_material", "node": 0, "material": "red"}, "has no mesh to take a material"),
    ({"op": "set_light", "material": "sun", "emission": [1, 1, 1]}, "'sun' does not exist"),
    ({"op": "remove_mesh", "mesh": "tri"}, r"'tri' is used by node 2 \('cube'\) and 1 more"),
    ({"op": "remove_mesh", "mesh": "cone"}, "mesh 'cone' does not exist"),
    ({"op": "update_vertices", "mesh": "cone", "vertices": TRIANGLE[0]}, "'cone' does not exist"),
    (
        {"op": "replace_mesh", "mesh": "cone", "vertices": TRIANGLE[0], "faces": TRIANGLE[1]},
        "mesh 'cone' does not exist",
    ),
    ({"op": "add_mesh", "mesh": "tri", "vertices": QUAD[0], "faces": QUAD[1]}, "already exists"),
    ({"op": "add_node", "id": 3, "name": "x", "kind": "static"}, "node id 3 is already in use"),
    ({"op": "add_node", "name": "x", "parent": 9, "kind": "static"}, "node 9 does not exist"),
    ({"op": "add_node", "name": "x", "kind": "static", "mesh": "tri"}, "mesh but no material"),
    ({"op": "add_node", "name": "x", "kind": "static", "material": "red"}, "material but no mesh"),
    (
        {"op": "add_node", "name": "x", "kind": "static", "mesh": "cone", "material": "red"},
        "mesh 'cone' does not exist",
    ),
    (
        {"op": "add_node", "name": "x", "kind": "static", "mesh": "tri", "material": "gold"},
        "material 'gold' does not exist",
    ),
    ({"op": "remove_node", "node": -1}, "node -1 does not exist"),
    # mesh data
    ({"op": "update_vertices", "mesh": "quad", "vertices": TRIANGLE[0]}, "has 4 vertices, got 3"),
    (
        {"op": "add_mesh", "mesh": "m", "vertices": TRIANGLE[0], "faces": [[0, 1, 3]]},
        "mesh 'm': a face refers to a vertex that does not exist",
    ),
    (
        {
            "op": "add_mesh",
            "mesh": "m",
            "vertices": [[0, 0, 0], [1, 0, float("nan")], [0, 1, 0]],
            "faces": [[0, 1, 2]],
        },
        "vertices must be finite",
    ),
    (
        {
            "op": "replace_mesh",
            "mesh": "tri",
            "vertices": [[0, 0, np.inf]] * 3,
            "faces": [[0, 1, 2]],
        },
        "vertices must be finite",
    ),
    (
        {"op": "add_mesh", "mesh": "m", "vertices": [[0, 0], [1, 0], [0, 1]], "faces": [[0, 1, 2]]},
        r"vertices must have shape \(N, 3\) with N >= 1, not \(3, 2\)",
    ),
    (
        {"op": "add_mesh", "mesh": "m", "vertices": [[0, 0, 0], [1, 0]], "faces": [[0, 1, 2]]},
        r"vertices must be a rectangular \(N, 3\) array",
    ),
    (
        {"op": "add_mesh", "mesh": "m", "vertices": [["a", "b", "c"]], "faces": [[0, 0, 0]]},
        "vertex coordinates must be numbers",
    ),
    (
        {"op": "add_mesh", "mesh": "m", "vertices": TRIANGLE[0], "faces": [[0.0, 1.0, 2.0]]},
        "face indices must be integers",
    ),
    (
        {"op": "add_mesh", "mesh": "m", "vertices": TRIANGLE[0], "faces": [[True, False, True]]},
        "face indices must be integers",
    ),
    (
        {"op": "add_mesh", "mesh": "m", "vertices": TRIANGLE[0], "faces": [[0, -1, 2]]},
        "face indices must be non-negative",
    ),
    (
        {"op": "add_mesh", "mesh": "m", "vertices": TRIANGLE[0], "faces": []},
        r"faces must have shape \(N, 3\) with N >= 1, not \(0,\)",
    ),
    # values
    (
        {"op": "set_transform", "node": 1, "transform": {"translate": [0, float("inf"), 0]}},
        r"op 1 \(set_transform\): transform.translate.1: Input should be a finite number",
    ),
    ({"op": "set_transform", "node": 1, "transform": {"scale": 0}}, "transform is singular"),
    ({"op": "set_light", "material": "light", "emission": [1, -1, 1]}, "emission.1"),
    ({"op": "set_sky", "radiance": [float("nan"), 0, 0]}, "radiance.0"),
    ({"op": "set_camera", "camera": {"look_at": [0, 0, 5]}}, "look_at must differ from position"),
    ({"op": "set_render", "render": {"spp": 0}}, "render.spp"),
    ({"op": "set_material", "name": "", "material": {}}, "name: String should have at least 1"),
    (
        {"op": "set_material", "name": "m", "material": {"shiny": True}},
        "material.diffuse.shiny: unknown",
    ),
    ({"op": "set_kind", "node": True, "kind": "rigid"}, "node: a node is referred to by its id"),
    ({"op": "set_kind", "node": 1.0, "kind": "rigid"}, "node: a node is referred to by its id"),
    ({"op": "add_node", "id": -2, "name": "x", "kind": "static"}, "id: a node id is an integer"),
    ({"op": "set_sky", "radiance": [0, 0, 0], "extra": 1}, "extra: unknown key"),
    ({"op": "set_transform", "node": 1}, "transform: Field required"),
    # the op itself
    ({"op": "explode"}, "op 1: unknown operation 'explode' \\(known: set_transform, "),
    ({"node": 1}, "op 1: unknown operation None"),
    (["set_sky"], "op 1: an operation is an object, not list"),
    ({"op": ["set_sky"]}, r"op 1: unknown operation \['set_sky'\]"),
]


@pytest.mark.parametrize("op, message", REFUSED, ids=[f"{i}" for i in range(len(REFUSED))])
def test_invalid_ops_are_refused_with_a_clear_message(op, message):
    """Each refusal names the op's index and kind and the reason, in one line."""
    state = small_state()
    with pytest.raises(SceneError, match=message) as info:
        apply(state, {"op": "set_sky", "radiance": [1, 1, 1]}, op)
    text = str(info.value)
    assert "\n" not in text
    kind = op.get("op") if isinstance(op, dict) else None
    assert text.startswith(f"op 1 ({kind}): " if str(kind) in so.OP_KINDS else "op 1: "), text


def test_ambiguous_and_unknown_names():
    state = apply(small_state(), {"op": "add_node", "name": "floor", "kind": "static"})
    with pytest.raises(SceneError, match=r"2 nodes are named 'floor' \(ids 1, 5\): use an id"):
        apply(state, {"op": "set_kind", "node": "floor", "kind": "rigid"})
    assert apply(state, {"op": "set_kind", "node": 1, "kind": "rigid"}).nodes[1].kind == "rigid"
    with pytest.raises(SceneError, match=r"op 2 \(set_kind\): 2 nodes are named 'floor'"):
        apply(
            small_state(),
            {"op": "set_kind", "node": "floor", "kind": "rigid"},
            {"op": "add_node", "name": "floor", "kind": "static"},
            {"op": "set_kind", "node": "floor", "kind": "rigid"},
        )
    with pytest.raises(SceneError, match=r"op 2 \(set_kind\): no node is named 'handle'"):
        apply(
            small_state(),
            {"op": "set_kind", "node": "handle", "kind": "static"},
            {"op": "remove_node", "node": "cube"},
            {"op": "set_kind", "node": "handle", "kind": "rigid"},
        )
    removed = apply(state, {"op": "remove_node", "node": 5})
    assert apply(removed, {"op": "set_kind", "node": "floor", "kind": "rigid"}).nodes[1].kind == (
        "rigid"
    )


def test_a_failing_op_changes_nothing():
    """The first ops succeed, the last fails: the input state and its tables are untouched."""
    state = small_state()
    tables = (dict(state.nodes), dict(state.meshes), dict(state.materials))
    with pytest.raises(SceneError, match=r"op 3 \(remove_mesh\)"):
        apply(
            state,
            {"op": "set_transform", "node": 1, "transform": {"translate": [9, 9, 9]}},
            {"op": "remove_node", "node": "lamp"},
            {"op": "add_mesh", "mesh": "new", "vertices": TRIANGLE[0], "faces": TRIANGLE[1]},
            {"op": "remove_mesh", "mesh": "quad"},
        )
    assert (dict(state.nodes), dict(state.meshes), dict(state.materials)) == tables
    np.testing.assert_array_equal(state.nodes[1].transform, np.eye(4))


def test_apply_ops_refuses_what_is_not_an_op_model():
    with pytest.raises(SceneError, match=r"op 0: not an operation model \(dict\)"):
        so.apply_ops(small_state(), [{"op": "set_sky", "radiance": [0, 0, 0]}])


# --- models -----------------------------------------------------------------------------------


def test_arrays_are_private_read_only_copies():
    """Lists and arrays give equal ops; changing the caller's array later changes nothing."""
    vertices = np.array(TRIANGLE[0], dtype=np.float32)
    op = so.AddMesh(mesh="m", vertices=vertices, faces=np.array(TRIANGLE[1], dtype=np.uint8))
    assert op == so.parse_op(
        {"op": "add_mesh", "mesh": "m", "vertices": TRIANGLE[0], "faces": TRIANGLE[1]}
    )
    assert op.vertices.dtype == np.float64 and op.faces.dtype == np.int64
    vertices[0, 0] = 5.0
    assert op.vertices[0, 0] == 0.0 and not op.vertices.flags.writeable
    assert op != so.AddMesh(mesh="m", vertices=vertices, faces=TRIANGLE[1])
    with pytest.raises(Exception, match="frozen"):
        op.mesh = "other"


def test_parse_op_and_parse_ops():
    op = so.parse_op({"op": "set_kind", "node": "cube", "kind": "rigid"})
    assert op == so.SetKind(node="cube", kind="rigid")
    assert so.parse_op(op) is op
    assert so.parse_ops([op, {"op": "remove_node", "node": 3}])[1] == so.RemoveNode(node=3)
    with pytest.raises(SceneError, match=r"^op \(set_kind\): kind: Input should be 'static'"):
        so.parse_op({"op": "set_kind", "node": 1, "kind": "soft"})
    with pytest.raises(SceneError, match=r"^op 1 \(remove_node\): node: Field required"):
        so.parse_ops([op, {"op": "remove_node"}])


def test_every_op_kind_is_in_the_union():
    assert set(so.OP_KINDS) == {
        "set_transform", "set_material", "assign_material", "set_light", "set_camera", "set_sky",
        "set_lights", "set_render", "add_mesh", "remove_mesh", "update_vertices", "replace_mesh",
        "add_node", "remove_node", "set_kind",
    }  # fmt: skip


# --- commits ----------------------------------------------------------------------------------


def test_apply_commit_sets_the_version_and_is_idempotent():
    state = small_state(version=3)
    commit = so.Commit(4, [so.SetSky(radiance=(1.0, 1.0, 1.0))])
    assert isinstance(commit.ops, tuple)
    new = so.apply_commit(state, commit)
    assert new.version == 4 and new.sky.radiance == (1.0, 1.0, 1.0)
    assert so.apply_commit(new, commit) is new, "re-delivery of an applied commit is a no-op"
    assert so.apply_commit(new, so.Commit(2, [so.RemoveNode(node=99)])) is new


def test_a_commit_gap_needs_a_snapshot():
    state = small_state(version=3)
    for version in (5, 6):
        with pytest.raises(so.CommitGap, match=f"commit {version} cannot follow version 3") as info:
            so.apply_commit(state, so.Commit(version, [so.SetSky(radiance=(1.0, 1.0, 1.0))]))
        assert isinstance(info.value, SceneError)


def test_a_failing_commit_raises_scene_error_not_gap():
    with pytest.raises(SceneError, match=r"op 0 \(remove_node\): node 99") as info:
        so.apply_commit(small_state(version=3), so.Commit(4, [so.RemoveNode(node=99)]))
    assert not isinstance(info.value, so.CommitGap)


# --- properties -------------------------------------------------------------------------------

node_refs = st.one_of(st.integers(-1, 7), st.sampled_from(["room", "floor", "cube", "lamp", "x"]))
mesh_names = st.sampled_from(["quad", "tri", "new"])
material_names = st.sampled_from(["white", "red", "light", "new"])
small = st.floats(-10, 10, allow_nan=False)
ops = st.one_of(
    st.builds(so.SetTransform, node=node_refs,
              transform=st.builds(fmt.Transform, translate=st.tuples(small, small, small))),
    st.builds(so.AssignMaterial, node=node_refs, material=material_names),
    st.builds(so.SetMaterial, name=material_names, material=st.just(fmt.DiffuseMaterial())),
    st.builds(so.SetKind, node=node_refs, kind=st.sampled_from(["static", "rigid", "dynamic"])),
    st.builds(so.RemoveNode, node=node_refs),
    st.builds(so.RemoveMesh, mesh=mesh_names),
    st.builds(so.AddMesh, mesh=mesh_names, vertices=st.just(TRIANGLE[0]),
              faces=st.just(TRIANGLE[1])),
    st.builds(so.UpdateVertices, mesh=mesh_names, vertices=st.just(QUAD[0])),
    st.builds(so.AddNode, id=st.none() | st.integers(0, 8), name=st.sampled_from(["x", "cube"]),
              parent=st.none() | node_refs, kind=st.just("rigid"),
              mesh=st.none() | mesh_names, material=st.none() | material_names),
)  # fmt: skip


@settings(max_examples=150, derandomize=True)
@given(st.lists(ops, max_size=12))
def test_random_op_sequences_keep_the_invariants_and_share_the_rest(sequence):
    """Whatever is applied, one op at a time: either a SceneError, or a consistent state in
    which every node, mesh and material the op did not name is the old object."""
    state = small_state()
    for op in sequence:
        try:
            new = so.apply_ops(state, [op])
        except SceneError:
            continue
        check_state(new)
        touched = set()
        if isinstance(op, so.RemoveNode):
            touched = set(state.nodes) - set(new.nodes)
        elif hasattr(op, "node"):
            touched = {op.node} | {n.id for n in state.nodes.values() if n.name == op.node}
        assert_shares_all_but(
            state,
            new,
            nodes=touched,
            meshes={getattr(op, "mesh", None)},
            materials={getattr(op, "name", None)},
        )
        state = new

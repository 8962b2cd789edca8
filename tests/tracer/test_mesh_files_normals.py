"""Shading normals from mesh files (``tracer.scene.mesh_files``, ``tracer.scene.vertex_normals``):
a file's own normals (glTF NORMAL, OBJ vn, PLY nx ny nz) load in the mesh's vertex order and
move with the file's node matrices as normals do; files without them shade flat unless the
scene asks for ``smooth_angle``; ``normals: "flat"`` drops them; bad options are errors."""

import json

import numpy as np
import pytest
import trimesh

from tests.helpers import tiny_scene, write_json
from tracer.errors import SceneError
from tracer.scene import format as fmt
from tracer.scene import vertex_normals
from tracer.scene.gltf_features import gltf_json, has_normals
from tracer.scene.loader import load_scene
from tracer.scene.mesh_files import load_file_model, load_mesh_file

# rotation about z by 30 degrees, then a non-uniform scale with a mirror in x, then a shift
ANGLE = np.radians(30.0)
NODE_MATRIX = np.array(
    [
        [-2.0 * np.cos(ANGLE), 2.0 * np.sin(ANGLE), 0.0, 1.0],
        [0.5 * np.sin(ANGLE), 0.5 * np.cos(ANGLE), 0.0, -2.0],
        [0.0, 0.0, 3.0, 0.5],
        [0.0, 0.0, 0.0, 1.0],
    ]
)


def unit(v):
    v = np.asarray(v, np.float64)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def odd_normals(count: int) -> np.ndarray:
    """Unit normals no renderer would compute from the triangles (so they must come from the
    file), exactly representable in float32."""
    rng = np.random.default_rng(7)
    return unit(rng.normal(size=(count, 3))).astype(np.float32).astype(np.float64)


def gltf_with_normals(path, normals: bool = True, matrix=NODE_MATRIX):
    """An icosphere as a glTF node under ``matrix``, with ``odd_normals`` if ``normals``."""
    ball = trimesh.creation.icosphere(1)
    mesh = trimesh.Trimesh(ball.vertices, ball.faces, process=False)
    written = odd_normals(len(mesh.vertices))
    if normals:
        mesh.vertex_normals = written
    scene = trimesh.Scene()
    scene.add_geometry(mesh, node_name="ball", geom_name="ball", transform=matrix)
    scene.export(path, include_normals=normals)
    return mesh, written


def test_gltf_normals_load_exactly_and_move_with_the_node_matrix(tmp_path):
    """The NORMAL attribute, in vertex order: unchanged in the file's own mesh (the node
    matrix is the part's transform) and, baked with the node matrix, moved by its inverse
    transpose (rotation, non-uniform scale and a mirror), the faces reversed by the mirror."""
    path = tmp_path / "ball.glb"
    mesh, written = gltf_with_normals(path)
    assert has_normals(gltf_json(path))
    model = load_file_model(path, "ball.glb", "m#")
    (own,) = model.meshes.values()
    np.testing.assert_array_equal(own.vertices, mesh.vertices.astype(np.float32))
    np.testing.assert_allclose(own.normals, unit(written), rtol=0, atol=1e-15)
    matrix = model.parts[0][1]  # as the file stores it
    np.testing.assert_allclose(matrix, NODE_MATRIX, rtol=0, atol=1e-7)

    baked = load_mesh_file(path)
    linear = np.linalg.inv(matrix[:3, :3]).T
    expected = unit(written @ linear.T)
    np.testing.assert_allclose(baked.normals, expected, rtol=0, atol=1e-14)
    np.testing.assert_array_equal(baked.faces, mesh.faces[:, ::-1])  # mirrored: reversed


def test_gltf_without_normal_is_flat(tmp_path):
    """glTF without NORMAL shades flat (the glTF spec), though trimesh would compute some."""
    path = tmp_path / "ball.glb"
    gltf_with_normals(path, normals=False)
    assert not has_normals(gltf_json(path))
    assert load_mesh_file(path).normals is None
    (own,) = load_file_model(path, "ball.glb", "m#").meshes.values()
    assert own.normals is None


def test_gltf_part_without_normals_is_flat_next_to_one_with(tmp_path):
    """A merged file whose parts differ: the part without normals gets its face normals,
    a vertex per corner; the other keeps its own."""
    smooth = trimesh.creation.icosphere(1)
    smooth = trimesh.Trimesh(smooth.vertices, smooth.faces, process=False)
    smooth.vertex_normals = odd_normals(len(smooth.vertices))
    box = trimesh.creation.box()
    flat = trimesh.Trimesh(box.vertices + 3.0, box.faces, process=False)
    path = tmp_path / "two.gltf"
    scene = trimesh.Scene()
    scene.add_geometry(smooth, node_name="ball", geom_name="ball")
    scene.add_geometry(flat, node_name="box", geom_name="box")
    for name, data in scene.export(file_type="gltf", include_normals=None).items():
        (tmp_path / name).write_bytes(data)
    path = tmp_path / "model.gltf"
    document = json.loads(path.read_text())
    for mesh in document["meshes"]:  # keep NORMAL on the ball only
        if mesh["name"] == "box":
            mesh["primitives"][0]["attributes"].pop("NORMAL", None)
    path.write_text(json.dumps(document))
    merged = load_mesh_file(path)
    on_ball = merged.vertices[:, 0] < 2.0  # the box lies beyond x = 2.5
    np.testing.assert_allclose(merged.normals[on_ball], smooth.vertex_normals, rtol=0, atol=1e-7)
    assert np.count_nonzero(~on_ball) == 3 * len(box.faces)  # a vertex per corner
    box_faces = merged.faces[~on_ball[merged.faces[:, 0]]]
    face_normals = trimesh.Trimesh(merged.vertices, box_faces, process=False).face_normals
    np.testing.assert_allclose(merged.normals[box_faces], face_normals[:, None, :].repeat(3, 1))


OBJ_WITH_VN = """\
v 0 0 0
v 1 0 0
v 1 1 0
v 0 1 0
vn 0 0 1
vn 0.6 0 0.8
vn 0 0.6 0.8
vn -0.8 0 0.6
f 1//2 2//1 3//3
f 1//4 3//2 4//3
"""


def test_obj_vn_follow_their_corners(tmp_path):
    """OBJ normals indexed apart from the positions: every face corner keeps the position and
    the normal its ``v//vn`` pair names (trimesh splits vertices to make them per vertex)."""
    path = tmp_path / "quad.obj"
    path.write_text(OBJ_WITH_VN)
    positions = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], np.float64)
    vn = np.array([[0, 0, 1], [0.6, 0, 0.8], [0, 0.6, 0.8], [-0.8, 0, 0.6]], np.float64)
    corners = [[(1, 2), (2, 1), (3, 3)], [(1, 4), (3, 2), (4, 3)]]
    mesh = load_mesh_file(path)
    assert mesh.normals is not None and len(mesh.vertices) > 4  # split
    for face, expected in zip(mesh.faces, corners, strict=True):
        for vertex, (v, n) in zip(face, expected, strict=True):
            np.testing.assert_array_equal(mesh.vertices[vertex], positions[v - 1])
            np.testing.assert_allclose(mesh.normals[vertex], vn[n - 1], rtol=0, atol=1e-15)


def test_obj_without_vn_on_every_face_is_flat(tmp_path):
    """trimesh keeps no normals when some faces of an OBJ name none: the mesh is flat."""
    path = tmp_path / "mixed.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nvn 0 0 1\nf 1//1 2//1 3//1\nf 2 4 3\n")
    assert load_mesh_file(path).normals is None


def test_ply_normals(tmp_path):
    """PLY ``nx ny nz`` per vertex, in vertex order; a PLY or STL without them is flat."""
    ball = trimesh.creation.icosphere(1)
    written = odd_normals(len(ball.vertices))
    mesh = trimesh.Trimesh(ball.vertices, ball.faces, vertex_normals=written, process=False)
    path = tmp_path / "ball.ply"
    path.write_bytes(trimesh.exchange.ply.export_ply(mesh, vertex_normal=True))
    loaded = load_mesh_file(path)
    np.testing.assert_array_equal(loaded.vertices, ball.vertices.astype(np.float32))
    np.testing.assert_allclose(loaded.normals, unit(written), rtol=0, atol=1e-7)
    for suffix in (".ply", ".stl"):
        bare = tmp_path / f"bare{suffix}"
        trimesh.Trimesh(ball.vertices, ball.faces, process=False).export(bare)
        assert load_mesh_file(bare).normals is None


def shape(path: str, **options) -> fmt.MeshFile:
    return fmt.MeshFile(path=path, **options)


def corner_normals(mesh) -> np.ndarray:
    return mesh.normals[mesh.faces]


def test_smooth_angle_keeps_a_cubes_edges_and_smooths_a_sphere(tmp_path):
    """At 30 degrees a cube stays creased (every corner has its face's normal, 24 vertices)
    and an icosphere (faces about 12 degrees apart) is smooth: one normal per vertex, close
    to the radial direction; an STL triangle soup of the same sphere smooths the same way."""
    box = trimesh.creation.box()
    trimesh.Trimesh(box.vertices, box.faces, process=False).export(tmp_path / "cube.obj")
    cube = load_mesh_file(tmp_path / "cube.obj", shape("cube.obj", smooth_angle=30.0))
    assert cube.vertices.shape == (24, 3)
    face_normals = trimesh.Trimesh(cube.vertices, cube.faces, process=False).face_normals
    np.testing.assert_allclose(corner_normals(cube), face_normals[:, None, :].repeat(3, 1))
    rounded = load_mesh_file(tmp_path / "cube.obj", shape("cube.obj", smooth_angle=100.0))
    assert rounded.vertices.shape == (8, 3)  # at 100 degrees the edges smooth too

    ball = trimesh.creation.icosphere(2)
    trimesh.Trimesh(ball.vertices, ball.faces, process=False).export(tmp_path / "ball.obj")
    smooth = load_mesh_file(tmp_path / "ball.obj", shape("ball.obj", smooth_angle=30.0))
    assert smooth.vertices.shape == ball.vertices.shape
    radial = unit(smooth.vertices)
    assert np.max(np.linalg.norm(smooth.normals - radial, axis=1)) < 0.03
    assert load_mesh_file(tmp_path / "ball.obj").normals is None  # flat unless asked

    trimesh.Trimesh(ball.vertices, ball.faces, process=False).export(tmp_path / "ball.stl")
    soup = load_mesh_file(tmp_path / "ball.stl", shape("ball.stl", smooth_angle=30.0))
    assert np.max(np.linalg.norm(soup.normals - unit(soup.vertices), axis=1)) < 0.03


def test_smooth_angle_splits_vertices_with_their_uvs(tmp_path):
    """Where a vertex is split along a crease, each copy keeps its UV: every face corner has
    the position and UV the file gives it."""
    box = trimesh.creation.box()
    uv = np.column_stack([box.vertices[:, 0] + 0.5, box.vertices[:, 1] * 2.0 + 0.25])
    mesh = trimesh.Trimesh(box.vertices, box.faces, process=False)
    mesh.visual = trimesh.visual.TextureVisuals(uv=uv)
    mesh.export(tmp_path / "cube.obj")
    plain = load_mesh_file(tmp_path / "cube.obj")
    creased = load_mesh_file(tmp_path / "cube.obj", shape("cube.obj", smooth_angle=30.0))
    assert creased.uvs is not None and len(creased.vertices) > len(plain.vertices)
    np.testing.assert_array_equal(creased.vertices[creased.faces], plain.vertices[plain.faces])
    np.testing.assert_array_equal(creased.uvs[creased.faces], plain.uvs[plain.faces])


def test_normals_flat_drops_the_files_normals(tmp_path):
    path = tmp_path / "quad.obj"
    path.write_text(OBJ_WITH_VN)
    assert load_mesh_file(path, shape("quad.obj", normals="flat")).normals is None
    (own,) = load_file_model(path, "quad.obj", "m#", shape("x", normals="flat")).meshes.values()
    assert own.normals is None


def scene_with_files(tmp_path, *objects) -> dict:
    data = tiny_scene()
    data["objects"] = [*data["objects"][:1], *objects, data["objects"][2]]
    return write_json(tmp_path / "scene.json", data)


def test_scene_options_reach_the_meshes(tmp_path):
    """Through a scene: the same file with and without options gives different meshes (the
    default one keyed as before), with the scene's material or the file's own, and the file's
    materials once."""
    box = trimesh.creation.box()
    trimesh.Trimesh(box.vertices, box.faces, process=False).export(tmp_path / "cube.obj")
    path = scene_with_files(
        tmp_path,
        {"name": "a", "shape": "cube.obj", "material": "grey"},
        {"name": "b", "shape": {"type": "file", "path": "cube.obj", "smooth_angle": 100},
         "material": "grey"},
        {"name": "c", "shape": {"type": "file", "path": "cube.obj", "smooth_angle": 100}},
        {"name": "d", "shape": "cube.obj"},
    )  # fmt: skip
    state = load_scene(path)
    assert state.meshes["file:cube.obj"].normals is None
    assert state.meshes["file:cube.obj?smooth_angle=100.0"].normals.shape == (8, 3)
    by_name = {node.name: node for node in state.nodes.values()}
    assert state.meshes[by_name["c/cube"].mesh].normals.shape == (8, 3)
    assert state.meshes[by_name["d/cube"].mesh].normals is None
    assert by_name["c/cube"].material == by_name["d/cube"].material


@pytest.mark.parametrize(
    "options, problem",
    [
        ({"smooth_angle": 0}, "greater than 0"),
        ({"smooth_angle": -10}, "greater than 0"),
        ({"smooth_angle": 181}, "less than or equal to 180"),
        ({"smooth_angle": "soft"}, "smooth_angle"),
        ({"normals": "smooth"}, "'file' or 'flat'"),
        ({"normals": "flat", "smooth_angle": 30}, "give one of them"),
    ],
)
def test_bad_normal_options_are_scene_errors(tmp_path, options, problem):
    trimesh.creation.box().export(tmp_path / "cube.obj")
    path = scene_with_files(
        tmp_path, {"shape": {"type": "file", "path": "cube.obj", **options}, "material": "grey"}
    )
    with pytest.raises(SceneError) as info:
        load_scene(path)
    message = str(info.value)
    assert problem in message and "\n" not in message, message


def test_creased_normals_on_random_meshes():
    """On bumpy closed spheres at random angles: corners keep their positions, normals are
    unit and the same bits on every call; at 180 degrees nothing is split and the normals are
    the area-weighted ones."""
    rng = np.random.default_rng(3)
    for _ in range(5):
        ball = trimesh.creation.icosphere(2)
        vertices = ball.vertices * rng.uniform(0.8, 1.2, size=(len(ball.vertices), 1))
        angle = float(rng.uniform(1.0, 90.0))
        source, faces, normals = vertex_normals.creased(vertices, ball.faces, angle)
        np.testing.assert_array_equal(vertices[source][faces], vertices[ball.faces])
        np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, rtol=0, atol=1e-15)
        again = vertex_normals.creased(vertices, ball.faces, angle)
        assert normals.tobytes() == again[2].tobytes()
        source, faces, normals = vertex_normals.creased(vertices, ball.faces, 180.0)
        np.testing.assert_array_equal(source, np.arange(len(vertices)))
        smooth = vertex_normals.area_weighted(vertices, ball.faces, np.zeros_like(vertices))
        np.testing.assert_allclose(normals, smooth, rtol=0, atol=1e-14)

"""Loading scenes from disk (``tracer.scene.loader``) and compiling them
(``tracer.compiled.scene``).

Valid scenes load; every bad input raises SceneError with a one-line message naming the
problem (docs/scene-format.md, "What the loader checks"); a mesh file alone is a scene with a
camera that sees it and a light; transforms place and orient triangles as documented.
"""

import base64
import json
import math
import os
import shutil

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st

from tests.helpers import (
    CORNELL,
    GLTF_BOX,
    SCENES,
    project,
    tiny_scene,
    write_json,
    write_mesh,
)
from tracer.compiled.scene import STATIC_KEY, compile_scene, static_key
from tracer.compiled.zero_area import zero_area_mask
from tracer.errors import SceneError
from tracer.render import render_lines
from tracer.scene import format as fmt
from tracer.scene.loader import (
    DEFAULT_LIGHT,
    MAX_SCENE_FILE_BYTES,
    framing_camera,
    load_scene,
    load_warnings,
)
from tracer.shading.camera import camera_array, primary_ray


def load_error(path) -> str:
    """The SceneError message for loading and compiling ``path`` (which must fail)."""
    with pytest.raises(SceneError) as info:
        compile_scene(load_scene(path))
    message = str(info.value)
    assert message and "\n" not in message, f"not one line: {message!r}"
    return message


def scene_with(tmp_path, **changes):
    """Write the tiny scene with top-level ``changes`` and return its path."""
    return write_json(tmp_path / "scene.json", tiny_scene(**changes))


def object_scene(tmp_path, shape, transform=None, material="clay"):
    """The tiny scene with its cube replaced by one object "thing" (material "clay"), which
    comes first: it is ``objects.0`` and ``meshes[0]``."""
    data = tiny_scene()
    data["materials"]["clay"] = {"reflectance": [0.5, 0.4, 0.3]}
    obj = {"name": "thing", "shape": shape, "material": material}
    if transform is not None:
        obj["transform"] = transform
    data["objects"] = [obj, data["objects"][0], data["objects"][2]]
    return write_json(tmp_path / "scene.json", data)


def quick_render(scene, width=8, height=6, spp=1) -> np.ndarray:
    camera = fmt.override(scene.camera, width=width, height=height)
    settings_ = fmt.override(scene.render, spp=spp, max_depth=3)
    return render_lines(scene, 0, height, camera, settings_, threads=1).rgb


# --- valid scenes ---------------------------------------------------------------------------


@pytest.mark.parametrize(
    "path",
    sorted(SCENES.glob("*/scene.json")) + sorted(SCENES.glob("*/*.gltf")),
    ids=lambda p: p.parent.name,
)
def test_sample_scenes_load(path):
    """Every sample scene loads and compiles: triangles, an emitter (an emissive triangle, or a
    light or sky with power), and bounds that contain every mesh."""
    data = load_scene(path)
    scene = compile_scene(data)
    assert scene.stats.triangles == sum(len(m.faces) for m in data.world_meshes()) > 0
    assert scene.stats.emissive_triangles > 0 or (scene.lights.weight > 0.0).any()
    lo, hi = np.array(scene.stats.bounds_min), np.array(scene.stats.bounds_max)
    slack = 1e-6 * np.abs(np.concatenate([lo, hi])).max()  # geometry is stored in float32
    for mesh in data.world_meshes():
        assert (mesh.vertices >= lo - slack).all() and (mesh.vertices <= hi + slack).all()
    assert len(scene.material_names) == len(data.materials)


def test_tiny_scene_renders(tiny_scene_file):
    """The built-in shapes of the tiny scene compile and render to a lit, finite image."""
    scene = compile_scene(load_scene(tiny_scene_file))
    assert scene.stats.triangles == 2 + 12 + 2
    rgb = quick_render(scene, spp=2)
    assert np.isfinite(rgb).all() and rgb.max() > 0


def test_render_space_keeps_geometry(tmp_path):
    """Compilation stores each cluster of static geometry next to its origin by a
    power-of-two-friendly offset, but the triangles are the world triangles minus that offset,
    exactly (for representable data); the cluster's instance adds the offset back exactly."""
    data = tiny_scene()
    data["objects"][1]["transform"] = {"translate": [1024.0, 2048.0, -512.0]}
    path = write_json(tmp_path / "far.json", data)
    loaded = load_scene(path)
    scene = compile_scene(loaded)
    world = {m.node: m.vertices[m.faces] for m in loaded.world_meshes()}
    assert scene.static_clusters == 2  # the far object is baked on its own
    for k in range(scene.static_clusters):
        accel = scene.meshes[static_key(k)]
        owner = accel.owner[accel.bvh.tri_prim]
        expected = np.stack([world[node][local] for node, local in owner]) - accel.center
        assert np.array_equal(accel.bvh.tri_verts.reshape(-1, 3, 3), expected.astype(np.float32))
        shift = scene.arrays.inst_xform[k].reshape(3, 4)
        assert np.array_equal(shift[:, :3], np.eye(3))
        assert np.array_equal(shift[:, 3] + scene.origin, accel.center)


# --- the JSON file itself -------------------------------------------------------------------


def test_missing_file(tmp_path):
    """A path that does not exist."""
    assert "no such file" in load_error(tmp_path / "nope.json")


def test_directory_is_not_a_scene(tmp_path):
    """A directory is refused as a scene."""
    assert "not a file" in load_error(tmp_path)


def test_unknown_suffix(tmp_path):
    """A file of an unknown type is refused, listing the known ones."""
    path = tmp_path / "scene.txt"
    path.write_text("{}")
    message = load_error(path)
    assert "'.txt'" in message and ".json" in message and ".obj" in message


@pytest.mark.parametrize(
    "text, message",
    [
        ("{", "not valid JSON"),
        ("", "not valid JSON"),
        ('{"format": "tilerender/1",}', "not valid JSON"),
        (b"\xff\xfe{}", "not valid JSON"),
        ('{"camera": {"vfov_deg": NaN}}', "NaN"),
        ('{"camera": {"vfov_deg": Infinity}}', "Infinity"),
        ('{"camera": {"vfov_deg": -Infinity}}', "-Infinity"),
        ('{"render": {"spp": 1e400}}', "finite"),
        ("[]", "valid dictionary"),
        ('"scene"', "valid dictionary"),
    ],
)
def test_unparseable_json(tmp_path, text, message):
    """Broken JSON, JSON's non-standard NaN/Infinity, overflowing numbers, and JSON that is not
    an object are refused with a message that says so."""
    path = tmp_path / "scene.json"
    if isinstance(text, bytes):
        path.write_bytes(text)
    else:
        path.write_text(text)
    assert message in load_error(path)


def test_deeply_nested_json(tmp_path):
    """A small file of 100,000 nested brackets is bad input like any other, not a crash."""
    path = tmp_path / "scene.json"
    path.write_text("[" * 100_000 + "]" * 100_000)
    assert "JSON" in load_error(path)


@pytest.mark.parametrize(
    "where, key",
    [
        ([], "lamps"),
        (["camera"], "fov"),
        (["render"], "samples"),
        (["materials", "grey"], "colour"),
        (["objects", 1], "scale"),
        (["objects", 1, "transform"], "translation"),
        (["objects", 0, "shape"], "radius"),
    ],
)
def test_unknown_keys(tmp_path, where, key):
    """A misspelled key anywhere is refused, with its location in the message."""
    data = tiny_scene()
    node = data
    for step in where:
        node = node[step]
    node[key] = 1
    message = load_error(write_json(tmp_path / "scene.json", data))
    location = ".".join(str(s) for s in where)
    assert f": {location}" in message and f"{key}: unknown key" in message


@pytest.mark.parametrize(
    "change, location",
    [
        ({"camera": {"width": "wide"}}, "camera.width"),
        ({"camera": {"position": [0, 1]}}, "camera.position"),
        ({"render": {"spp": 2.5}}, "render.spp"),
        ({"render": {"seed": "seven"}}, "render.seed"),
        ({"materials": {"grey": {"reflectance": "grey"}}}, "materials.grey.diffuse.reflectance"),
        ({"materials": []}, "materials"),
        ({"objects": {"a": 1}}, "objects"),
    ],
)
def test_wrong_types(tmp_path, change, location):
    """Values of the wrong type are refused, naming the field."""
    message = load_error(scene_with(tmp_path, **change))
    assert f"{location}: " in message or f"{location}." in message


@pytest.mark.parametrize(
    "change, location, words",
    [
        ({"camera": {"width": 0}}, "camera.width", "greater than or equal to 1"),
        ({"camera": {"height": 0}}, "camera.height", "greater than or equal to 1"),
        ({"camera": {"width": 16385}}, "camera.width", "less than or equal to 16384"),
        ({"camera": {"height": 10**30}}, "camera.height", "less than or equal to 16384"),
        ({"render": {"spp": 0}}, "render.spp", "greater than or equal to 1"),
        ({"render": {"max_depth": 0}}, "render.max_depth", "greater than or equal to 1"),
    ],
)
def test_out_of_range_settings(tmp_path, change, location, words):
    """Image sizes of 0 or above the maximum and zero samples are refused with the limit."""
    message = load_error(scene_with(tmp_path, **change))
    assert f"{location}: " in message and words in message


def test_undefined_material(tmp_path):
    """An object using an undefined material: the message names it and the defined ones."""
    path = object_scene(tmp_path, {"type": "box"}, material="gold")
    message = load_error(path)
    assert "'gold'" in message and "not defined" in message and "clay, grey, lamp" in message


@pytest.mark.filterwarnings("ignore:overflow encountered:RuntimeWarning")
@pytest.mark.parametrize(
    "transform, words",
    [
        ({"scale": 0}, "singular"),
        ({"scale": [1, 1, 0]}, "singular"),
        ({"matrix": [[1, 0, 0, 0], [0, 0, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]}, "singular"),
        ({"matrix": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [1, 0, 0, 1]]}, "affine"),
        ({"matrix": np.eye(4).tolist(), "translate": [0, 1, 0]}, "not both"),
        ({"scale": 1e300}, "singular"),
        ({"translate": [1e300, 0, 0], "scale": 1e300}, "singular"),
    ],
)
def test_bad_transforms(tmp_path, transform, words):
    """Singular, non-affine and over-specified transforms are refused, located at the object."""
    message = load_error(object_scene(tmp_path, {"type": "box"}, transform))
    assert "objects.0.transform" in message and words in message


@pytest.mark.filterwarnings("ignore:overflow encountered:RuntimeWarning")
def test_transform_to_infinity(tmp_path):
    """A finite, non-singular transform that sends vertices to infinity is refused, naming the
    object."""
    matrix = [[1e308, 1e308, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]
    message = load_error(object_scene(tmp_path, {"type": "box"}, {"matrix": matrix}))
    assert message.startswith("thing: ") and "infinity" in message


def test_objects_placed_too_far_are_refused_by_name(tmp_path):
    """An object moved so far that float64 cannot tell its vertices apart is refused with that
    reason and its name (each far object is baked on its own, so the scene's extent alone is no
    reason), and so is one beyond what float32 bounds hold."""
    data = tiny_scene()
    data["objects"][0]["transform"] = {"translate": [-1e39, 0, 0]}
    data["objects"][1]["transform"] = {"translate": [1e39, 0, 0]}
    message = load_error(write_json(tmp_path / "scene.json", data))
    assert "float64 cannot tell its vertices apart" in message and "1e+39" in message
    data = tiny_scene()
    data["objects"][1]["transform"] = {"translate": [1e31, 0, 0], "scale": 1e16}
    message = load_error(write_json(tmp_path / "scene.json", data))
    assert "beyond the range of float32 bounds" in message


# --- mesh file references -------------------------------------------------------------------


def ico(path):
    mesh = trimesh.creation.icosphere(subdivisions=1)
    return write_mesh(path, mesh.vertices, mesh.faces)


def test_mesh_reference_loads(tmp_path):
    """A relative reference into a subdirectory loads that mesh."""
    (tmp_path / "meshes").mkdir()
    ico(tmp_path / "meshes" / "ball.obj")
    data = load_scene(object_scene(tmp_path, "meshes/ball.obj"))
    assert len(data.world_meshes()[0].faces) == 80


@pytest.mark.parametrize("reference", ["../outside.obj", "sub/../../outside.obj"])
def test_reference_leaving_the_directory(tmp_path, reference):
    """A reference that climbs out of the scene's directory is refused, even though the file
    it names exists."""
    scene_dir = tmp_path / "scene"
    (scene_dir / "sub").mkdir(parents=True)
    ico(tmp_path / "outside.obj")
    message = load_error(object_scene(scene_dir, reference))
    assert reference in message and "may not leave" in message


def test_absolute_reference(tmp_path):
    """An absolute path is refused, even to an existing file inside the directory."""
    target = ico(tmp_path / "ball.obj")
    message = load_error(object_scene(tmp_path, str(target)))
    assert "relative" in message


@pytest.mark.skipif(not hasattr(os, "symlink"), reason="needs symbolic links")
def test_symlink_leaving_the_directory(tmp_path):
    """A symbolic link inside the directory pointing outside it is refused."""
    scene_dir = tmp_path / "scene"
    scene_dir.mkdir()
    ico(tmp_path / "outside.obj")
    (scene_dir / "link.obj").symlink_to(tmp_path / "outside.obj")
    assert "may not leave" in load_error(object_scene(scene_dir, "link.obj"))


def test_missing_mesh_file(tmp_path):
    """A reference to a file that does not exist."""
    message = load_error(object_scene(tmp_path, "ghost.obj"))
    assert "ghost.obj" in message and "no such file" in message


def test_reference_to_a_directory(tmp_path):
    """A reference to a directory is not a mesh."""
    (tmp_path / "meshes").mkdir()
    assert "no such file" in load_error(object_scene(tmp_path, "meshes"))


def test_reference_to_the_scene_directory_itself(tmp_path):
    """``"shape": "."`` (the scene's own directory) is bad input, not a crash."""
    load_error(object_scene(tmp_path, "."))


@pytest.mark.parametrize("where", ["relative", "absolute"])
def test_gltf_resources_may_not_leave_the_directory(tmp_path, where):
    """A glTF inside the scene directory whose buffer lies outside it is refused too (the
    containment rule holds for files the mesh file itself refers to)."""
    gltf = json.loads(GLTF_BOX.read_text())
    uri = gltf["buffers"][0]["uri"]
    (tmp_path / "outside.bin").write_bytes(base64.b64decode(uri.split(",", 1)[1]))
    scene_dir = tmp_path / "scene"
    scene_dir.mkdir()
    outside = tmp_path / "outside.bin"
    gltf["buffers"][0]["uri"] = "../outside.bin" if where == "relative" else str(outside)
    write_json(scene_dir / "model.gltf", gltf)
    assert "model.gltf" in load_error(object_scene(scene_dir, "model.gltf"))
    # The same file with its buffer beside it loads.
    shutil.copy(outside, scene_dir / "inside.bin")
    gltf["buffers"][0]["uri"] = "inside.bin"
    write_json(scene_dir / "model.gltf", gltf)
    assert len(load_scene(scene_dir / "scene.json").world_meshes()[0].faces) == 12


def test_scene_file_too_large(tmp_path):
    """A scene file above the size limit is refused without being parsed."""
    path = tmp_path / "scene.json"
    with open(path, "wb") as f:
        f.truncate(MAX_SCENE_FILE_BYTES + 1)
    assert "larger than" in load_error(path)


def test_reference_to_a_non_mesh_file(tmp_path):
    """A reference to a file trimesh cannot read as a mesh (here the scene itself)."""
    path = object_scene(tmp_path, "scene.json")
    assert "cannot read mesh file" in load_error(path)


def write_obj(path, text):
    path.write_text(text)
    return path.name


@pytest.mark.parametrize(
    "text, words",
    [
        ("# nothing here\n", "no meshes"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\n", "no triangles"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 5\n", "cannot read"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 2 -9\n", "cannot read"),
        ("v 0 0 0\nv 1 0 nan\nv 0 1 0\nf 1 2 3\n", "NaN"),
        ("v 0 0 0\nv 1 0 inf\nv 0 1 0\nf 1 2 3\n", "infinite"),
        ("v 0 0 0\nv 1 1 1\nv 2 2 2\nf 1 2 3\nf 1 1 2\nf 3 3 3\n", "zero area"),
    ],
    ids=["empty", "points-only", "index-out-of-range", "negative-index", "nan", "inf", "flat"],
)
def test_bad_obj_files(tmp_path, text, words):
    """OBJ files without triangles, with face indices out of range, with NaN or infinite
    coordinates, or with only zero-area triangles give a SceneError, never a crash."""
    name = write_obj(tmp_path / "bad.obj", text)
    message = load_error(object_scene(tmp_path, name))
    assert words in message


def test_degenerate_triangles_are_dropped(tmp_path):
    """Zero-area triangles mixed into a mesh (a repeated vertex, collinear vertices, a single
    point) are dropped, counted in stats.degenerate_triangles, and the scene still renders."""
    box = trimesh.creation.box(extents=(1, 1, 1))
    n = len(box.vertices)
    vertices = np.concatenate([box.vertices, [[0, 0, 0], [0.25, 0.25, 0.25], [0.5, 0.5, 0.5]]])
    faces = np.concatenate([box.faces, [[0, 0, 1], [n, n + 1, n + 2], [n + 1, n + 1, n + 1]]])
    write_mesh(tmp_path / "box.obj", vertices, faces)
    scene = compile_scene(load_scene(object_scene(tmp_path, "box.obj")))
    assert scene.stats.degenerate_triangles == 3
    assert scene.stats.triangles == 12 + 3 + 2 + 2
    static = scene.meshes[STATIC_KEY]
    assert static.bvh.tri_prim.shape == (12 + 2 + 2,)
    dropped = static.owner[static.bvh.tri_prim]
    assert not (np.isin(dropped[:, 1], [12, 13, 14]) & (dropped[:, 0] == 0)).any()
    rgb = quick_render(scene)
    assert np.isfinite(rgb).all() and rgb.max() > 0


@settings(max_examples=30)
@given(
    a=st.tuples(*[st.integers(-8, 8)] * 3),
    b=st.tuples(*[st.integers(-8, 8)] * 3),
    t=st.sampled_from([0.0, 0.25, 0.5, 1.0, 2.0, -3.0]),
    scale=st.sampled_from([1.0, 2.0**-20, 0.75, 2.0**30]),
)
def test_zero_area_mask_is_exact(a, b, t, scale):
    """zero_area_mask flags exactly the triangles whose float32 vertices are collinear: a point
    on the line through two others (exact in float32 here) is flagged; moving it off the line
    by one float32 step of its largest coordinate, along any axis, is not."""
    a = np.array(a, np.float64) * scale
    b = np.array(b, np.float64) * scale
    c = a + t * (b - a)
    tri = np.concatenate([a, b, c]).astype(np.float32)
    assert np.array_equal(tri.astype(np.float64), np.concatenate([a, b, c]))
    assert zero_area_mask(tri[None])[0]
    d = b - a
    step = float(np.spacing(np.float32(max(np.abs(c).max(), scale))))
    for axis in range(3):
        if not d.any() or (np.count_nonzero(d) == 1 and d[axis] != 0):
            continue  # the line is a point, or runs along this axis: the nudge stays on it
        moved = tri.copy()
        moved[6 + axis] = np.float32(c[axis] + step)
        assert float(moved[6 + axis]) == c[axis] + step
        assert not zero_area_mask(moved[None])[0]


def test_zero_area_mask_on_mixed_magnitudes():
    """A triangle 2^-149 off collinear (float32's smallest step, next to coordinates near 1) is
    not of zero area: the exact cross product is (5 * 2^-149, -5 * 2^-149, 0)."""
    tri = np.array([0, 0, -1, 5, 5, 3, 1.25, 1.25, 2.0**-149], np.float32)
    assert tri[8] > 0
    assert not zero_area_mask(tri[None])[0]


# --- transforms and winding -----------------------------------------------------------------


def outward(vertices, faces, centre) -> np.ndarray:
    """For each triangle, whether its counter-clockwise normal points away from ``centre``."""
    v = vertices[faces]
    normal = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    return np.einsum("ij,ij->i", normal, v.mean(axis=1) - centre) > 0


@pytest.mark.parametrize(
    "transform",
    [
        {},
        {"rotate": [30, 60, 90], "translate": [1, 2, 3]},
        {"scale": [-1, 1, 1]},
        {"scale": [-2, -3, 0.5], "rotate": [10, 0, 0]},
        {"scale": -1},
        {"matrix": [[0, 1, 0, 4], [1, 0, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]},
    ],
    ids=["identity", "rigid", "mirror-x", "mirror-2-axes", "point-reflection", "swap-xy"],
)
@pytest.mark.parametrize("shape", [{"type": "box"}, {"type": "sphere", "subdivisions": 1}])
def test_transforms_keep_faces_outward(tmp_path, transform, shape):
    """Loaded vertices are the transform applied to the shape, and front faces still face out:
    mirroring transforms (negative determinant) reverse the winding."""
    data = load_scene(object_scene(tmp_path, shape, transform or None))
    mesh = data.world_meshes()[0]
    m = fmt.Transform.model_validate(transform).to_matrix()
    centre = m[:3, 3]
    assert outward(mesh.vertices, mesh.faces, centre).all()
    # The vertices are the documented transform of the untransformed shape.
    plain = load_scene(object_scene(tmp_path, shape)).world_meshes()[0]
    np.testing.assert_allclose(mesh.vertices, plain.vertices @ m[:3, :3].T + m[:3, 3], atol=1e-12)
    # And the renderer's copy (render space, leaf order) keeps that orientation.
    scene = compile_scene(data)
    static = scene.meshes[STATIC_KEY]
    rows = static.tri_material == scene.material_names.index("clay")
    tri = static.bvh.tri_verts[rows].astype(np.float64).reshape(-1, 3, 3)
    faces = np.arange(tri.shape[0] * 3).reshape(-1, 3)
    assert outward(tri.reshape(-1, 3), faces, centre - scene.origin).all()


def test_mirrored_one_sided_light_still_lights(tmp_path):
    """A one-sided lamp mirrored through its own plane (scale z = -1) still faces the way its
    winding says: the same image as the unmirrored lamp, which faces down at the floor."""
    data = tiny_scene()
    path = write_json(tmp_path / "a.json", data)
    data["objects"][2]["transform"]["scale"] = [1, 1, -1]
    mirrored = write_json(tmp_path / "b.json", data)
    a = quick_render(compile_scene(load_scene(path)), spp=2)
    b = quick_render(compile_scene(load_scene(mirrored)), spp=2)
    assert a.max() > 0
    # The lamp's plane is z = 0 in its own frame, so mirroring z changes no vertex; with the
    # winding reversed its back faces the floor and the floor goes dark.
    assert b.sum() < 0.2 * a.sum()


# --- a mesh file alone is a scene -----------------------------------------------------------


def corners(lo, hi) -> np.ndarray:
    return np.array(
        [[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])]
    )


def assert_camera_sees(camera, lo, hi):
    """All eight corners of the box [lo, hi] project inside the image, in front of the camera."""
    xy = project(camera, corners(lo, hi))
    assert np.isfinite(xy).all(), "a corner is behind the camera"
    assert (xy[:, 0] >= 0).all() and (xy[:, 0] <= camera.width).all(), xy
    assert (xy[:, 1] >= 0).all() and (xy[:, 1] <= camera.height).all(), xy


def test_projection_matches_the_renderer():
    """The test's pinhole projection inverts the renderer's primary rays (so the framing tests
    below check the camera the renderer really uses)."""
    camera = fmt.Camera(position=(1, 2, 3), look_at=(-1, 0, 0.5), width=64, height=48, vfov_deg=50)
    cam = camera_array(camera.position, camera.look_at, camera.up, 50, 64, 48)
    rng = np.random.default_rng(0)
    for fx, fy in rng.uniform(0, [64, 48], size=(20, 2)):
        o, d = primary_ray(cam, 64, 48, fx, fy)
        xy = project(camera, (np.array(o) + 3.0 * np.array(d))[None])[0]
        np.testing.assert_allclose(xy, [fx, fy], atol=1e-9)


def light_faces(data, centre):
    """Whether the default light's triangles face ``centre`` by their winding."""
    light = data.world_meshes()[-1]
    return ~outward(light.vertices, light.faces, centre)


def test_gltf_alone_is_a_scene():
    """Box.gltf (no emitter): its geometry with node transforms, its material, a camera that
    sees all of it and a one-sided default light facing it; it renders lit."""
    data = load_scene(GLTF_BOX)
    meshes = data.world_meshes()
    assert len(meshes) == 2 and meshes[-1].name == DEFAULT_LIGHT
    box = meshes[0]
    assert len(box.faces) == 12
    lo, hi = box.vertices.min(axis=0), box.vertices.max(axis=0)
    # The file's root node turns the box's y into -z; its mesh is the unit cube.
    np.testing.assert_allclose(hi - lo, [1, 1, 1], atol=1e-6)
    assert_camera_sees(data.camera, lo, hi)
    light = data.materials[meshes[-1].material]
    assert max(light.emission) > 0 and light.two_sided is False
    assert light_faces(data, 0.5 * (lo + hi)).all()
    assert quick_render(compile_scene(data), 16, 12, spp=4).mean() > 0.01


def test_the_gltf_features_sample_takes_the_files_camera_and_lights():
    """scenes/gltf-features: the file's camera and its spot, point and directional lights
    (no default light), smooth normals on the sphere, the floor's UVs tiled by its texture
    transform; the normal map's approximation is its one warning."""
    path = SCENES / "gltf-features" / "gltf-features.gltf"
    data = load_scene(path)
    assert [light.type for light in data.lights] == ["spot", "point", "sun"]
    assert DEFAULT_LIGHT not in data.materials
    assert data.camera.position == (0.0, 2.2, 5.2) and (data.camera.width, data.camera.height) == (
        640,
        480,
    )
    meshes = {key.rsplit(":", 1)[-1]: mesh for key, mesh in data.meshes.items()}
    assert meshes["sphere"].normals is not None
    assert np.ptp(meshes["floor"].uvs, axis=0).max() > 4.0  # scale 4, turned by 0.3 rad
    (warning,) = load_warnings(path)
    assert "normalTexture approximated" in warning


def test_emissive_gltf_gets_no_default_light(tmp_path):
    """A glTF whose material emits keeps its own lighting: no default light, and its
    emissiveFactor, baseColorFactor and doubleSided become the material."""
    mesh = trimesh.creation.box()
    mesh.visual = trimesh.visual.TextureVisuals(
        material=trimesh.visual.material.PBRMaterial(
            baseColorFactor=[255, 0, 0, 255], emissiveFactor=[2.0, 1.0, 0.5], doubleSided=False
        )
    )
    mesh.export(tmp_path / "lamp.glb")
    data = load_scene(tmp_path / "lamp.glb")
    meshes = data.world_meshes()
    assert len(meshes) == 1 and meshes[0].name != DEFAULT_LIGHT
    material = data.materials[meshes[0].material]
    assert material.emission == (2.0, 1.0, 0.5) and material.reflectance == (1.0, 0.0, 0.0)
    assert material.two_sided is False


@pytest.mark.parametrize("suffix", [".obj", ".ply", ".stl", ".glb"])
def test_mesh_file_alone_is_a_scene(tmp_path, suffix):
    """An OBJ, PLY, STL or GLB file alone: its triangles, a framing camera, a default light
    facing the mesh; it renders lit."""
    mesh = trimesh.creation.icosphere(subdivisions=2)
    mesh.apply_transform(np.diag([3.0, 0.5, 1.0, 1.0]))
    mesh.apply_translation([10, 20, 30])
    path = write_mesh(tmp_path / f"thing{suffix}", mesh.vertices, mesh.faces)
    data = load_scene(path)
    meshes = data.world_meshes()
    assert [len(m.faces) for m in meshes] == [320, 2]
    lo, hi = meshes[0].vertices.min(axis=0), meshes[0].vertices.max(axis=0)
    np.testing.assert_allclose([lo, hi], [mesh.bounds[0], mesh.bounds[1]], rtol=1e-6)
    assert_camera_sees(data.camera, lo, hi)
    assert light_faces(data, 0.5 * (lo + hi)).all()
    scene = compile_scene(data)
    assert scene.stats.emissive_triangles == 2
    assert quick_render(scene, 16, 12, spp=4).mean() > 0.01


def test_bad_mesh_file_alone(tmp_path):
    """A mesh file alone that cannot be read, or holds no triangles, is a SceneError."""
    (tmp_path / "junk.glb").write_bytes(b"not a glb at all")
    assert "junk.glb" in load_error(tmp_path / "junk.glb")
    (tmp_path / "points.obj").write_text("v 0 0 0\nv 1 0 0\n")
    assert "no triangle" in load_error(tmp_path / "points.obj")


@settings(max_examples=50)
@given(
    centre=st.tuples(*[st.floats(-1e6, 1e6)] * 3),
    extent=st.tuples(*[st.floats(1e-3, 1e3)] * 3),
)
def test_framing_camera_sees_any_bounds(centre, extent):
    """For any box (long, flat, far from the origin) the framing camera sees all 8 corners."""
    lo = np.array(centre) - np.array(extent)
    hi = np.array(centre) + np.array(extent)
    camera = framing_camera(lo, hi)
    assert_camera_sees(camera, lo, hi)
    # Not absurdly far: the bounding sphere spans a good part of the vertical field of view.
    radius = 0.5 * np.linalg.norm(hi - lo)
    distance = np.linalg.norm(np.subtract(camera.position, camera.look_at))
    assert radius / distance > 0.5 * math.sin(math.radians(camera.vfov_deg) / 2)


def test_cornell_scene_file_matches_its_json():
    """load_scene keeps the file's camera, render settings and material order."""
    raw = json.loads(CORNELL.read_text())
    data = load_scene(CORNELL)
    assert data.camera.width == raw["camera"]["width"]
    assert data.render.spp == raw["render"]["spp"]
    assert list(data.materials) == list(raw["materials"])
    assert [m.name for m in data.world_meshes()] == [o["name"] for o in raw["objects"]]

"""Cameras from a glTF file (``tracer.scene.gltf_cameras``, ``gltf_placement``): a perspective
camera's view is its node's (the ray through the image centre is the node's -Z, the top edge
``yfov / 2`` above it), a file alone takes its first one at its aspect ratio, a scene takes one
with ``camera.from_object``; orthographic cameras and malformed ones are handled as documented;
the CLI answers bad cameras as bad input."""

import math

import numpy as np
import pydantic
import pytest
import trimesh

from tests.gltf_files import add_node, write_gltf
from tests.helpers import tiny_scene, write_json
from tracer.errors import SceneError
from tracer.scene import format as fmt
from tracer.scene.loader import load_scene, load_warnings
from tracer.shading.camera import camera_array, primary_ray

YFOV = 0.6
PERSPECTIVE = {"type": "perspective", "name": "lens",
               "perspective": {"yfov": YFOV, "aspectRatio": 16 / 9, "znear": 0.1}}  # fmt: skip
ORTHOGRAPHIC = {"type": "orthographic", "name": "plan",
                "orthographic": {"xmag": 1, "ymag": 1, "znear": 0.1, "zfar": 10}}  # fmt: skip


def rotation(axis, degrees):
    """(x, y, z, w) of a turn, and its 4x4 matrix."""
    half = math.radians(degrees) / 2
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    quaternion = [*(math.sin(half) * axis), math.cos(half)]
    return quaternion, trimesh.transformations.rotation_matrix(math.radians(degrees), axis)


def filmed_box(tmp_path, cameras, nodes, name="filmed.gltf"):
    """The unit box with ``cameras`` and ``nodes`` (each ``(node, parent node or None)``)."""

    def edit(tree):
        tree["cameras"] = cameras
        for node, parent in nodes:
            parent_index = None if parent is None else add_node(tree, parent)
            add_node(tree, node, parent_index)

    return write_gltf(tmp_path / name, edit)


def rays(camera: fmt.Camera):
    """Directions through the image centre, the middle of its top edge and of its right edge."""
    array = camera_array(camera.position, camera.look_at, camera.up, camera.vfov_deg,
                         camera.width, camera.height)  # fmt: skip
    w, h = camera.width, camera.height
    return [np.array(primary_ray(array, w, h, fx, fy)[1]) for fx, fy in
            ((w / 2, h / 2), (w / 2, 0.0), (w, h / 2))]  # fmt: skip


def test_a_file_alone_looks_through_its_camera(tmp_path):
    """A camera node under a turned and moved parent: the camera sits at the node's origin, the
    centre ray is its -Z, the top edge is yfov/2 above toward its +Y, the right edge toward its
    +X; 640 wide at the file's aspect ratio."""
    q_parent, r_parent = rotation([0, 1, 0], 30)
    q_child, r_child = rotation([1, 0, 0], -20)
    parent = {"translation": [1, 2, 3], "rotation": q_parent}
    child = {"camera": 0, "translation": [0, 0, 4], "rotation": q_child}
    camera = load_scene(filmed_box(tmp_path, [PERSPECTIVE], [(child, parent)])).camera
    world = trimesh.transformations.translation_matrix([1, 2, 3]) @ r_parent
    world = world @ trimesh.transformations.translation_matrix([0, 0, 4]) @ r_child
    np.testing.assert_allclose(camera.position, world[:3, 3], atol=1e-12)
    assert (camera.width, camera.height) == (640, 360)
    centre, top, right = rays(camera)
    np.testing.assert_allclose(centre, -world[:3, 2], atol=1e-12)
    assert math.acos(np.clip(centre @ top, -1, 1)) == pytest.approx(YFOV / 2, abs=1e-12)
    assert top @ world[:3, 1] > 0 and right @ world[:3, 0] > 0
    assert camera.vfov_deg == pytest.approx(math.degrees(YFOV))


def test_the_first_perspective_camera_wins_and_orthographic_ones_warn(tmp_path):
    """An orthographic camera first, two perspective ones after: the first perspective one
    (480 high without an aspect ratio); the orthographic camera is named in a warning."""
    square = {"type": "perspective", "perspective": {"yfov": 1.0, "znear": 0.1}}
    nodes = [({"camera": 1}, None), ({"camera": 0, "translation": [0, 0, 7]}, None),
             ({"camera": 2, "translation": [0, 0, 9]}, None)]  # fmt: skip
    path = filmed_box(tmp_path, [square, ORTHOGRAPHIC, PERSPECTIVE], nodes)
    camera = load_scene(path).camera
    assert camera.position == (0, 0, 7) and (camera.width, camera.height) == (640, 480)
    assert load_warnings(path) == [
        "filmed.gltf: orthographic cameras ignored: only perspective cameras are supported"
    ]


def test_only_orthographic_cameras_fall_back_to_the_framing_camera(tmp_path):
    path = filmed_box(tmp_path, [ORTHOGRAPHIC], [({"camera": 0}, None)])
    plain = write_gltf(tmp_path / "plain.gltf", lambda tree: None)
    assert load_scene(path).camera == load_scene(plain).camera


@pytest.mark.parametrize(
    "cameras,node,words",
    [
        ([PERSPECTIVE], {"camera": 1}, ["camera 1", "does not exist"]),
        ([PERSPECTIVE], {"camera": -1}, ["does not exist"]),
        ([{"type": "fisheye"}], {"camera": 0}, ["cameras[0]", "unknown type 'fisheye'"]),
        ([{"type": "perspective"}], {"camera": 0}, ["perspective object"]),
        ([{"type": "perspective", "perspective": {"yfov": 3.2}}], {"camera": 0}, ["yfov"]),
        ([{"type": "perspective", "perspective": {"yfov": 1, "aspectRatio": 0}}], {"camera": 0},
         ["aspectRatio"]),
        ([PERSPECTIVE], {"camera": 0, "scale": [1, 1, 0]}, ["z axis"]),
    ],
)  # fmt: skip
def test_malformed_cameras_are_scene_errors(tmp_path, cameras, node, words):
    with pytest.raises(SceneError) as error:
        load_scene(filmed_box(tmp_path, cameras, [(node, None)]))
    assert "filmed.gltf" in str(error.value)
    for word in words:
        assert word in str(error.value)


def film_scene(tmp_path, camera: dict, **obj):
    """The tiny scene with the filmed box as an object ``asset`` and ``camera``."""
    data = tiny_scene(camera=camera)
    data["objects"].append({"name": "asset", "shape": "filmed.gltf", **obj})
    return write_json(tmp_path / "scene.json", data)


def test_a_scene_takes_a_files_camera_by_name(tmp_path):
    """``from_object``: the named camera (by its name or its node's) moved by the object's
    transform, at the scene's image size."""
    nodes = [({"camera": 0, "name": "front", "translation": [0, 0, 3]}, None),
             ({"camera": 1, "name": "side", "translation": [3, 0, 0]}, None)]  # fmt: skip
    filmed_box(tmp_path, [PERSPECTIVE, {**PERSPECTIVE, "name": "other"}], nodes)
    move = {"transform": {"translate": [0, 1, 0]}}
    by_default = {"from_object": "asset", "width": 30, "height": 20}
    camera = load_scene(film_scene(tmp_path, by_default, **move)).camera
    assert camera.position == (0, 1, 3) and (camera.width, camera.height) == (30, 20)
    np.testing.assert_allclose(rays(camera)[0], [0, 0, -1], atol=1e-12)
    for name in ("side", "other"):
        chosen = load_scene(film_scene(tmp_path, {"from_object": "asset", "name": name}, **move))
        assert chosen.camera.position == (3, 1, 0)
    assert load_warnings(tmp_path / "scene.json") == []


def test_a_scene_without_from_object_keeps_its_camera_and_warns(tmp_path):
    filmed_box(tmp_path, [PERSPECTIVE], [({"camera": 0}, None)])
    path = film_scene(tmp_path, tiny_scene()["camera"])
    assert load_scene(path).camera.position == (0.0, 1.5, 4.0)
    (warning,) = load_warnings(path)
    assert warning.startswith("filmed.gltf: cameras not used")


@pytest.mark.parametrize(
    "camera,obj,words",
    [
        ({"from_object": "asset", "name": "nothing"}, {}, ["no camera", "'nothing'", "front"]),
        ({"from_object": "asset", "name": "plan"}, {}, ["orthographic"]),
        ({"from_object": "asset"}, {"kind": "rigid"}, ["must be static"]),
    ],
)
def test_bad_from_object_is_a_scene_error(tmp_path, camera, obj, words):
    filmed_box(tmp_path, [PERSPECTIVE, ORTHOGRAPHIC],
               [({"camera": 0, "name": "front"}, None), ({"camera": 1}, None)])  # fmt: skip
    with pytest.raises(SceneError) as error:
        load_scene(film_scene(tmp_path, camera, **obj))
    for word in words:
        assert word in str(error.value)


def test_a_file_without_cameras_is_a_scene_error(tmp_path):
    write_gltf(tmp_path / "filmed.gltf", lambda tree: None)
    with pytest.raises(SceneError, match="no perspective camera"):
        load_scene(film_scene(tmp_path, {"from_object": "asset"}))


@pytest.mark.parametrize(
    "camera,words",
    [
        ({"from_object": "floor"}, ["no object named 'floor' has a mesh file"]),
        ({"from_object": "asset", "position": [0, 0, 1]}, ["position"]),
        ({"from_object": "asset", "aperture_radius": 0.1}, ["focus_distance"]),
    ],
)
def test_from_object_is_checked_with_the_format(camera, words):
    data = tiny_scene(camera=camera)
    data["objects"].append({"name": "asset", "shape": "filmed.gltf"})
    with pytest.raises(pydantic.ValidationError) as error:
        fmt.SceneFile.model_validate(data)
    for word in words:
        assert word in str(error.value)


def test_the_cli_answers_a_bad_camera_as_bad_input(tmp_path, capsys):
    """Exit code 2, one line naming the problem, no image (the API: tests/api/test_bad_inputs)."""
    from cli import main as cli_main

    path = filmed_box(tmp_path, [PERSPECTIVE], [({"camera": 3}, None)])
    code = cli_main.main(["render", str(path), "-o", str(tmp_path / "out.png")])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "uses camera 3" in err
    assert not (tmp_path / "out.png").exists()

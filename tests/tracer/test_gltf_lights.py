"""KHR_lights_punctual (``tracer.scene.gltf_lights``): a file's point, spot and directional
lights become the scene's, placed by their nodes' matrices (down the node's -Z), candela and
lux divided by 683; a spot's cone from its inner and outer angles; a bare file with lights gets
no default light; malformed lights are a SceneError."""

import math
from pathlib import Path

import numpy as np
import pytest

from tests.gltf_files import add_lights, add_node, light_node, write_gltf
from tests.helpers import tiny_scene, write_json, write_mesh
from tracer.errors import SceneError
from tracer.scene import format as fmt
from tracer.scene.gltf_lights import LUMENS_PER_WATT, file_lights
from tracer.scene.loader import DEFAULT_LIGHT, load_scene


def quaternion(axis, degrees):
    """glTF's (x, y, z, w) for a turn of ``degrees`` about ``axis``."""
    half = math.radians(degrees) / 2
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    return [*(math.sin(half) * axis), math.cos(half)]


def lit_box(tmp_path, lights, nodes, name="lit.gltf"):
    """The unit box with ``lights`` and light ``nodes`` (each ``(node, parent node or None)``;
    a parent is given as a node dict added first)."""

    def edit(tree):
        add_lights(tree, lights)
        for node, parent in nodes:
            parent_index = None if parent is None else add_node(tree, parent)
            add_node(tree, node, parent_index)

    return write_gltf(tmp_path / name, edit)


def test_point_light_placed_by_its_nodes_in_candela(tmp_path):
    """A point light in a child node: the parent turns 90 degrees about y and moves, the child
    moves along its parent's x; intensity times colour over 683 is W/sr."""
    parent = {"translation": [1, 2, 3], "rotation": quaternion([0, 1, 0], 90)}
    child = light_node(0, translation=[2, 0, 0])
    path = lit_box(tmp_path, [{"type": "point", "intensity": 683, "color": [1, 0.5, 0.25]}],
                   [(child, parent)])  # fmt: skip
    state = load_scene(path)
    (light,) = state.lights
    assert isinstance(light, fmt.PointLight)
    # +x of the parent is -z of the file after the quarter turn about y.
    np.testing.assert_allclose(light.position, [1, 2, 1], atol=1e-12)
    np.testing.assert_allclose(light.intensity, [1, 0.5, 0.25], rtol=1e-12)


def test_spot_light_points_down_its_nodes_minus_z(tmp_path):
    """A spot turned -90 degrees about x shines straight down; its outer cone is the cone
    angle and the band from the inner cone to it the falloff."""
    spot = {"type": "spot", "intensity": 2 * LUMENS_PER_WATT,
            "spot": {"innerConeAngle": 0.2, "outerConeAngle": 0.5}}  # fmt: skip
    node = light_node(0, translation=[0, 4, 0], rotation=quaternion([1, 0, 0], -90))
    (light,) = load_scene(lit_box(tmp_path, [spot], [(node, None)])).lights
    assert isinstance(light, fmt.SpotLight)
    np.testing.assert_allclose(light.position, [0, 4, 0])
    direction = np.subtract(light.look_at, light.position)
    np.testing.assert_allclose(direction / np.linalg.norm(direction), [0, -1, 0], atol=1e-12)
    assert light.intensity == (2.0, 2.0, 2.0)
    assert light.cone_angle_deg == pytest.approx(math.degrees(0.5))
    assert light.falloff_deg == pytest.approx(math.degrees(0.5 - 0.2))


def test_spot_defaults_are_the_specs(tmp_path):
    """Without angles a spot's cone is pi/4 with no inner cone: it fades over all of it."""
    (light,) = load_scene(lit_box(tmp_path, [{"type": "spot"}], [(light_node(0), None)])).lights
    assert light.cone_angle_deg == pytest.approx(45.0)
    assert light.falloff_deg == pytest.approx(45.0)
    np.testing.assert_allclose(np.subtract(light.look_at, light.position), [0, 0, -1])
    np.testing.assert_allclose(light.intensity, [1 / LUMENS_PER_WATT] * 3)


def test_directional_light_is_a_sun_toward_the_nodes_plus_z(tmp_path):
    """A directional light is a sun of radius 0 (delta), ``to_sun`` the node's +Z (light
    travels down -Z); lux over 683 is W/m^2; a scaling matrix node keeps the direction."""
    matrix = np.diag([2.0, 3.0, 0.5, 1.0])
    matrix[:3, :3] = matrix[:3, :3] @ np.array([[1, 0, 0], [0, 0, 1], [0, -1, 0]])  # +z -> +y
    node = light_node(0, matrix=matrix.T.reshape(-1).tolist())  # glTF is column-major
    sun = {"type": "directional", "intensity": 1366, "color": [1, 1, 0.5]}
    (light,) = load_scene(lit_box(tmp_path, [sun], [(node, None)])).lights
    assert isinstance(light, fmt.SunLight)
    np.testing.assert_allclose(light.to_sun, [0, 1, 0], atol=1e-12)
    np.testing.assert_allclose(light.irradiance, [2, 2, 1])
    assert light.angular_radius_deg == 0.0


def test_every_light_node_counts_and_black_lights_are_dropped(tmp_path):
    """Two nodes may use one light; a light of intensity 0 adds nothing."""
    lights = [{"type": "point", "intensity": 10}, {"type": "point", "intensity": 0}]
    nodes = [(light_node(0, translation=[0, 1, 0]), None),
             (light_node(0, translation=[0, 2, 0]), None), (light_node(1), None)]  # fmt: skip
    state = load_scene(lit_box(tmp_path, lights, nodes))
    assert [light.position for light in state.lights] == [(0, 1, 0), (0, 2, 0)]


def test_a_bare_file_with_lights_gets_no_default_light(tmp_path):
    """Lights in the file replace the default area light; a file whose lights are all black
    still gets it."""
    lit = load_scene(lit_box(tmp_path, [{"type": "point"}], [(light_node(0), None)]))
    assert DEFAULT_LIGHT not in lit.materials and len(lit.lights) == 1
    dark = load_scene(lit_box(tmp_path, [{"type": "point", "intensity": 0}],
                              [(light_node(0), None)], "dark.gltf"))  # fmt: skip
    assert DEFAULT_LIGHT in dark.materials and dark.lights == ()


@pytest.mark.parametrize(
    "light,words",
    [
        ({"type": "area"}, ["light 0", "unknown type 'area'"]),
        ({}, ["unknown type None"]),
        ({"type": "point", "intensity": -1}, ["intensity"]),
        ({"type": "point", "color": [1, 1]}, ["color"]),
        ({"type": "spot", "spot": {"innerConeAngle": 0.6, "outerConeAngle": 0.5}},
         ["innerConeAngle", "exceeds"]),
        ({"type": "spot", "spot": {"outerConeAngle": 2.0}}, ["outerConeAngle", "pi/2"]),
        ({"type": "spot", "spot": {"outerConeAngle": 0}}, ["outerConeAngle"]),
    ],
)  # fmt: skip
def test_malformed_lights_are_scene_errors(tmp_path, light, words):
    path = lit_box(tmp_path, [light], [(light_node(0), None)])
    with pytest.raises(SceneError) as error:
        load_scene(path)
    assert "lit.gltf" in str(error.value)
    for word in words:
        assert word in str(error.value)


@pytest.mark.parametrize("index", [1, -1, "0", True])
def test_a_node_naming_a_missing_light_is_a_scene_error(tmp_path, index):
    node = {"extensions": {"KHR_lights_punctual": {"light": index}}}
    with pytest.raises(SceneError, match="does not exist"):
        load_scene(lit_box(tmp_path, [{"type": "point"}], [(node, None)]))


def test_placement_moves_the_files_lights():
    """``file_lights`` with a placement: the object's matrix after the node's."""
    document = {
        "extensions": {"KHR_lights_punctual": {"lights": [{"type": "spot"}]}},
        "nodes": [{"translation": [1, 0, 0], **light_node(0)}],
        "scenes": [{"nodes": [0]}],
    }
    placement = np.eye(4)
    placement[:3, :3] = [[0, 0, 1], [0, 1, 0], [-1, 0, 0]]  # a quarter turn about y
    placement[:3, 3] = [0, 0, 5]
    (light,) = file_lights(document, "f.gltf", placement)
    np.testing.assert_allclose(light.position, [0, 0, 4], atol=1e-12)
    np.testing.assert_allclose(np.subtract(light.look_at, light.position), [-1, 0, 0], atol=1e-12)


def scene_with(tmp_path, shape, **obj) -> Path:
    """The tiny scene (one point light of its own) plus an object of ``shape``."""
    data = tiny_scene(lights=[{"type": "point", "position": [0, 5, 0], "intensity": [1, 1, 1]}])
    data["objects"].append({"name": "lamp", "shape": shape, **obj})
    return write_json(tmp_path / "scene.json", data)


def test_a_scene_adds_a_files_lights_when_the_object_asks(tmp_path):
    """``"lights": true``: the file's lights after the scene's own, moved by the object's
    transform after its parent's; without it, the scene's lights only."""
    lit_box(tmp_path, [{"type": "point", "intensity": 683}],
            [(light_node(0, translation=[0, 1, 0]), None)])  # fmt: skip
    shape = {"type": "file", "path": "lit.gltf", "lights": True}
    path = scene_with(tmp_path, shape, transform={"translate": [3, 0, 0], "scale": 2})
    own, added = load_scene(path).lights
    assert own.position == (0, 5, 0)
    np.testing.assert_allclose(added.position, [3, 2, 0])
    np.testing.assert_allclose(added.intensity, [1, 1, 1])
    assert len(load_scene(scene_with(tmp_path, "lit.gltf")).lights) == 1


def test_a_files_lights_need_a_static_object_and_a_gltf(tmp_path):
    lit_box(tmp_path, [{"type": "point"}], [(light_node(0), None)])
    shape = {"type": "file", "path": "lit.gltf", "lights": True}
    with pytest.raises(SceneError, match="must be static"):
        load_scene(scene_with(tmp_path, shape, kind="rigid"))
    write_mesh(tmp_path / "plain.obj", [[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])
    with pytest.raises(SceneError, match="not a glTF file"):
        load_scene(scene_with(tmp_path, {"type": "file", "path": "plain.obj", "lights": True}))

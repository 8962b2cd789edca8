"""The ``tilerender/1`` models (``tracer.scene.format``): what validates, what is refused, and
how transforms compose (docs/scene-format.md)."""

import numpy as np
import pydantic
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from tests.helpers import tiny_scene
from tracer import config
from tracer.scene import format as fmt

finite = st.floats(-1e3, 1e3, allow_nan=False)
angle = st.floats(-720.0, 720.0, allow_nan=False)
nonzero = st.floats(0.01, 100.0).flatmap(lambda x: st.sampled_from([x, -x]))


def test_tiny_scene_validates():
    """The test suite's own scene dict is a valid SceneFile (the other tests depend on it)."""
    scene = fmt.SceneFile.model_validate(tiny_scene())
    assert scene.format == fmt.FORMAT
    assert [o.name for o in scene.objects] == ["floor", "cube", "lamp"]


def test_defaults_match_the_documentation():
    """Defaults stated in docs/scene-format.md."""
    camera, render = fmt.Camera(), fmt.RenderSettings()
    assert (camera.width, camera.height, camera.vfov_deg) == (640, 480, 40.0)
    assert (render.spp, render.max_depth, render.rr_depth, render.seed) == (64, 8, 5, 0)
    material = fmt.DiffuseMaterial()
    assert material.reflectance == (0.8, 0.8, 0.8) and material.emission == (0.0, 0.0, 0.0)
    assert material.two_sided is True
    assert np.array_equal(fmt.Transform().to_matrix(), np.eye(4))


def test_shape_string_is_a_file_reference():
    """A plain string shape is shorthand for {"type": "file", "path": ...}."""
    obj = fmt.SceneObject.model_validate({"shape": "a/b.obj", "material": "m"})
    assert obj.shape == fmt.MeshFile(path="a/b.obj")


@settings(max_examples=60)
@given(
    translate=st.tuples(finite, finite, finite),
    rotate=st.tuples(angle, angle, angle),
    scale=st.tuples(nonzero, nonzero, nonzero),
)
def test_transform_composition(translate, rotate, scale):
    """translate/rotate/scale compose as T @ Rz @ Ry @ Rx @ S: scale first, then rotations
    about the fixed x, y and z axes in that order, then translation (checked against scipy's
    extrinsic 'xyz' Euler rotation)."""
    m = fmt.Transform(translate=translate, rotate=rotate, scale=scale).to_matrix()
    points = np.random.default_rng(0).normal(size=(5, 3))
    expected = Rotation.from_euler("xyz", rotate, degrees=True).apply(points * scale)
    expected += translate
    got = points @ m[:3, :3].T + m[:3, 3]
    np.testing.assert_allclose(got, expected, rtol=1e-12, atol=1e-9)
    assert np.array_equal(m[3], [0.0, 0.0, 0.0, 1.0])


def test_rotation_order_by_hand():
    """Rotations apply about x, then y, then z: +y turned 90 degrees about x is +z, and that
    turned 90 degrees about y is +x. A uniform scale is a number."""
    m = fmt.Transform(rotate=(90, 90, 0)).to_matrix()
    np.testing.assert_allclose(m[:3, :3] @ [0, 1, 0], [1, 0, 0], atol=1e-15)
    m = fmt.Transform(rotate=(0, 0, 90), translate=(1, 2, 3), scale=2).to_matrix()
    np.testing.assert_allclose(m @ [1, 0, 0, 1], [1, 4, 3, 1], atol=1e-15)


def test_matrix_is_row_major():
    """``matrix`` rows are the matrix's rows: the last column is the translation."""
    rows = ((0, -1, 0, 5), (1, 0, 0, 6), (0, 0, 1, 7), (0, 0, 0, 1))
    m = fmt.Transform(matrix=rows).to_matrix()
    np.testing.assert_array_equal(m @ [1, 0, 0, 1], [5, 7, 7, 1])


@pytest.mark.parametrize(
    "transform, message",
    [
        ({"scale": 0}, "singular"),
        ({"scale": [1, 0, 1]}, "singular"),
        ({"scale": 1e-200}, "singular"),
        ({"matrix": [[1, 0, 0, 0], [0, 0, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]}, "singular"),
        ({"matrix": [[1, 2, 3, 0], [2, 4, 6, 0], [0, 0, 1, 0], [0, 0, 0, 1]]}, "singular"),
        ({"matrix": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 1, 1]]}, "affine"),
        ({"matrix": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 2]]}, "affine"),
        ({"matrix": np.eye(4).tolist(), "translate": [1, 0, 0]}, "not both"),
        ({"matrix": np.eye(4).tolist(), "scale": 2}, "not both"),
        ({"matrix": np.eye(4).tolist(), "rotate": [0, 5, 0]}, "not both"),
        ({"matrix": np.eye(3).tolist()}, "matrix"),
        ({"translate": [0, float("nan"), 0]}, "finite"),
        ({"rotate": [float("inf"), 0, 0]}, "finite"),
        ({"scale": float("-inf")}, "finite"),
        ({"translation": [1, 2, 3]}, "Extra inputs"),
    ],
)
def test_bad_transforms(transform, message):
    """Singular, non-affine, non-finite, over-specified or misspelled transforms are refused."""
    with pytest.raises(pydantic.ValidationError, match=message):
        fmt.Transform.model_validate(transform)


def test_mirroring_transform_is_allowed():
    """A negative scale (a mirror) is not singular: it is valid, with a negative determinant."""
    m = fmt.Transform(scale=(-1, 1, 1)).to_matrix()
    assert np.linalg.det(m[:3, :3]) == -1.0


@pytest.mark.parametrize(
    "camera, message",
    [
        ({"width": 0}, "greater than or equal to 1"),
        ({"height": 0}, "greater than or equal to 1"),
        ({"width": config.MAX_IMAGE_SIDE + 1}, "less than or equal"),
        ({"width": config.MAX_IMAGE_SIDE, "height": config.MAX_IMAGE_SIDE}, "pixels"),
        ({"width": 2.5}, "integer"),
        ({"width": "wide"}, "integer"),
        ({"position": [0, 0, 0], "look_at": [0, 0, 0]}, "differ"),
        ({"position": [0, 0, 5], "look_at": [0, 0, 0], "up": [0, 0, 1]}, "parallel"),
        ({"up": [0, 0, 0]}, "parallel"),
        ({"vfov_deg": 0}, "greater than 0"),
        ({"vfov_deg": 180}, "less than 180"),
        ({"vfov_deg": float("nan")}, "vfov_deg"),
        ({"position": [0, 0]}, "position"),
        ({"position": [0, 0, float("inf")]}, "finite"),
        ({"fov": 40}, "Extra inputs"),
    ],
)
def test_bad_cameras(camera, message):
    """Cameras with no pixels, too many pixels, a degenerate frame or a bad field are refused."""
    with pytest.raises(pydantic.ValidationError, match=message):
        fmt.Camera.model_validate(camera)


def test_largest_camera_is_allowed():
    """The limits are inclusive: one side at the maximum, as many pixels as allowed."""
    side = config.MAX_IMAGE_SIDE
    fmt.Camera(width=side, height=config.MAX_PIXELS // side)
    fmt.Camera(width=1, height=1)


@pytest.mark.parametrize(
    "render, message",
    [
        ({"spp": 0}, "greater than or equal to 1"),
        ({"spp": config.MAX_SPP + 1}, "less than or equal"),
        ({"spp": 1.5}, "integer"),
        ({"max_depth": 0}, "greater than or equal to 1"),
        ({"max_depth": config.MAX_DEPTH + 1}, "less than or equal"),
        ({"rr_depth": 0}, "greater than or equal to 1"),
        ({"seed": -1}, "greater than or equal to 0"),
        ({"seed": 2**63}, "less than"),
        ({"samples": 4}, "Extra inputs"),
    ],
)
def test_bad_render_settings(render, message):
    """Sample counts, depths and seeds outside their documented ranges are refused."""
    with pytest.raises(pydantic.ValidationError, match=message):
        fmt.RenderSettings.model_validate(render)


@pytest.mark.parametrize(
    "material, message",
    [
        ({"reflectance": [1.5, 0, 0]}, "less than or equal to 1"),
        ({"reflectance": [-0.1, 0, 0]}, "greater than or equal to 0"),
        ({"emission": [-1, 0, 0]}, "greater than or equal to 0"),
        ({"emission": [float("inf"), 0, 0]}, "finite"),
        ({"type": "glass"}, "diffuse"),
        ({"colour": [1, 1, 1]}, "Extra inputs"),
    ],
)
def test_bad_materials(material, message):
    """Reflectance outside [0, 1], negative or infinite emission, unknown kinds are refused."""
    with pytest.raises(pydantic.ValidationError, match=message):
        fmt.DiffuseMaterial.model_validate(material)


@pytest.mark.parametrize(
    "shape, message",
    [
        ({"type": "sphere", "subdivisions": config.MAX_SPHERE_SUBDIVISIONS + 1}, "less than"),
        ({"type": "sphere", "radius": 0}, "greater than 0"),
        ({"type": "box", "size": [1, 1, -1]}, "greater than 0"),
        ({"type": "rectangle", "size": [1, 0]}, "greater than 0"),
        ({"type": "cone"}, "tag"),
        ({"type": "file", "path": ""}, "at least 1 character"),
        ({"type": "box", "radius": 1}, "Extra inputs"),
    ],
)
def test_bad_shapes(shape, message):
    """Built-in shapes with non-positive sizes, unknown types or stray keys are refused."""
    with pytest.raises(pydantic.ValidationError, match=message):
        fmt.SceneObject.model_validate({"shape": shape, "material": "m"})


@pytest.mark.parametrize("value", [2**63, 2**64])
def test_rr_depth_fits_the_kernel(value):
    """Every integer setting has an upper bound the kernel's int64 arguments can hold."""
    with pytest.raises(pydantic.ValidationError):
        fmt.RenderSettings(rr_depth=value)


def test_undefined_material_is_refused():
    """An object naming a material that is not defined is refused, naming both."""
    data = tiny_scene()
    data["objects"][1]["material"] = "gold"
    with pytest.raises(pydantic.ValidationError, match=r"'gold'.*not defined.*grey"):
        fmt.SceneFile.model_validate(data)


def _long_names(scene: dict, kind: str, name: str) -> dict:
    if kind == "material":
        scene["materials"][name] = scene["materials"].pop("grey")
        for obj in scene["objects"]:
            obj["material"] = name if obj["material"] == "grey" else obj["material"]
    elif kind == "object":
        scene["objects"][1]["name"] = name
    elif kind == "parent":
        scene["objects"][0]["name"] = scene["objects"][1]["parent"] = name
    elif kind == "animated object":
        scene["objects"][1]["kind"] = "rigid"
        scene["objects"][1]["name"] = name[: fmt.MAX_NAME]
        scene["animation"] = {"frames": 2, "objects": {name: [{"time": 0}]}}
    elif kind == "mesh path":
        scene["objects"][1]["shape"] = name + ".obj"
    elif kind == "texture":
        scene["materials"]["grey"]["texture"] = {"file": name + ".png"}
    return scene


@pytest.mark.parametrize(
    "kind", ["material", "object", "parent", "animated object", "mesh path", "texture"]
)
def test_names_have_a_length_limit(kind):
    """A name the scene chooses has at most MAX_NAME characters, a file reference at most
    MAX_PATH (a 10 MB material name used to be kept and returned by every GET)."""
    limit = fmt.MAX_PATH if kind in ("mesh path", "texture") else fmt.MAX_NAME
    longest = "n" * (limit - 4 if kind in ("mesh path", "texture") else limit)
    fmt.SceneFile.model_validate(_long_names(tiny_scene(), kind, longest))
    with pytest.raises(pydantic.ValidationError, match=f"at most {limit} characters"):
        fmt.SceneFile.model_validate(_long_names(tiny_scene(), kind, longest + "n"))


@pytest.mark.parametrize(
    "change, message",
    [
        ({"materials": {}}, "at least 1"),
        ({"objects": []}, "at least 1"),
        ({"format": "tilerender/2"}, "tilerender/1"),
        ({"lamps": []}, "Extra inputs"),
    ],
)
def test_bad_top_level(change, message):
    """No materials, no objects, another format version, or an unknown key are refused."""
    with pytest.raises(pydantic.ValidationError, match=message):
        fmt.SceneFile.model_validate(tiny_scene(**change))


def test_unknown_nested_keys_are_refused():
    """A misspelled key at any depth is an error, located by its path (which names the kind of
    a material, as it does a shape's, and of a camera: a view of its own or a file's)."""
    for path, where in (
        (["camera"], ["camera", "view"]),
        (["render"], ["render"]),
        (["materials", "grey"], ["materials", "grey", "diffuse"]),
        (["objects", 1, "transform"], ["objects", 1, "transform"]),
    ):
        data = tiny_scene()
        node = data
        for key in path:
            node = node[key]
        node["typo"] = 1
        with pytest.raises(pydantic.ValidationError) as info:
            fmt.SceneFile.model_validate(data)
        locations = [e["loc"] for e in info.value.errors()]
        assert (*where, "typo") in locations


def test_override():
    """override() returns a validated copy: None leaves a field alone, the original is
    unchanged, and a value the file format would refuse raises ValidationError."""
    camera = fmt.Camera(width=10, height=20)
    changed = fmt.override(camera, width=30, height=None)
    assert (changed.width, changed.height) == (30, 20)
    assert (camera.width, camera.height) == (10, 20)
    with pytest.raises(pydantic.ValidationError):
        fmt.override(camera, width=0)
    with pytest.raises(pydantic.ValidationError):
        fmt.override(fmt.RenderSettings(), spp=config.MAX_SPP + 1)
    with pytest.raises(pydantic.ValidationError):
        fmt.override(fmt.RenderSettings(), samples=3)


def test_models_are_frozen():
    """Validated models cannot be changed in place (a render cannot mutate its settings)."""
    with pytest.raises(pydantic.ValidationError):
        fmt.RenderSettings().spp = 3

"""Base-colour alpha as loaded (``tracer.scene.gltf_alpha``, ``tracer.shading.textures``): the
scene format's ``alpha``, glTF's ``alphaMode``, ``alphaCutoff`` and ``baseColorFactor`` alpha
times the base colour texture's alpha channel, the packed alpha table, and bad values."""

import numpy as np
import pydantic
import pytest
from PIL import Image

from tests.helpers import write_json
from tests.tracer.test_textures import gltf_document
from tracer.compiled.scene import compile_scene
from tracer.errors import SceneError
from tracer.scene import format as fmt
from tracer.scene.gltf_features import feature_warnings
from tracer.scene.loader import load_scene
from tracer.shading import textures


def rgba_checker(size: int = 4) -> np.ndarray:
    """RGBA, uint8 (size, size, 4): grey colour, alpha 255 on the checker's even squares and
    ``64`` on the odd ones (row 0 on top)."""
    image = np.full((size, size, 4), 200, np.uint8)
    y, x = np.mgrid[:size, :size]
    image[..., 3] = np.where((x + y) % 2 == 0, 255, 64)
    return image


def gltf_scene(tmp_path, materials: list[dict], image=None):
    """A JSON scene placing a glTF of one quad per material, loaded."""
    write_json(tmp_path / "quads.gltf", gltf_document(materials, image))
    scene = {"camera": {"position": [0, 0, 5], "look_at": [0, 0, 0], "width": 8, "height": 8},
             "materials": {"unused": {}},
             "objects": [{"name": "quads", "shape": "quads.gltf"}]}  # fmt: skip
    return load_scene(write_json(tmp_path / "scene.json", scene))


def pbr(name: str, factor=(1.0, 1.0, 1.0, 1.0), textured=False, **fields) -> dict:
    base = {"baseColorFactor": list(factor), "metallicFactor": 0.0}
    if textured:
        base["baseColorTexture"] = {"index": 0}
    return {"name": name, "pbrMetallicRoughness": base, **fields}


def test_gltf_alpha_modes_cutoff_and_factor(tmp_path):
    """OPAQUE (and no alphaMode) ignores alpha; MASK keeps its cutoff (0.5 by default); BLEND
    its factor; the factor's alpha is baseColorFactor[3] exactly."""
    state = gltf_scene(tmp_path, [
        pbr("plain", (1, 1, 1, 0.25)),
        pbr("opaque", (1, 1, 1, 0.25), alphaMode="OPAQUE"),
        pbr("mask", (1, 1, 1, 0.75), alphaMode="MASK"),
        pbr("cut", (1, 1, 1, 0.75), alphaMode="MASK", alphaCutoff=0.8),
        pbr("blend", (1, 1, 1, 0.3), alphaMode="BLEND"),
    ])  # fmt: skip
    alpha = {name.split("#")[1]: m.alpha for name, m in state.materials.items() if "#" in name}
    assert alpha["plain"] is None and alpha["opaque"] is None
    assert (alpha["mask"].mode, alpha["mask"].cutoff, alpha["mask"].value) == ("mask", 0.5, 0.75)
    assert (alpha["cut"].mode, alpha["cut"].cutoff) == ("mask", 0.8)
    assert (alpha["blend"].mode, alpha["blend"].value) == ("blend", 0.3)
    assert all(a is None or a.texture is None for a in alpha.values())


def test_gltf_texture_alpha_is_kept_per_texel(tmp_path):
    """A MASK material's base colour texture keeps its alpha channel as a grey image of its
    own; the packed table multiplies it (linear, not sRGB) by the factor's alpha. An OPAQUE
    material's texture keeps no alpha (no memory for it)."""
    image = rgba_checker()
    state = gltf_scene(tmp_path, [pbr("mask", (1, 1, 1, 0.5), True, alphaMode="MASK")], image)
    material = state.materials["quads.gltf#mask"]
    name = textures.alpha_image_name(material.alpha.texture.file)
    assert state.textures[name][..., 0].tolist() == image[..., 3].tolist()
    assert state.textures[material.texture.file].shape == (4, 4, 3)
    scene = compile_scene(state)
    row = scene.textures.alpha[scene.material_names.index("quads.gltf#mask")]
    assert row[textures.MODE] == textures.MASK and row[textures.VALUE] == 0.5
    entry = int(row[textures.ENTRY])
    first, width, height, _ = scene.textures.info[entry]
    texels = scene.textures.pixels[first : first + width * height, 0].reshape(height, width)
    np.testing.assert_array_equal(texels, image[..., 3] / np.float32(255.0))

    opaque = gltf_scene(tmp_path, [pbr("plain", textured=True)], image)
    assert not any(name.endswith(textures.ALPHA_SUFFIX) for name in opaque.textures)


def test_gltf_rgb_texture_gives_the_factor_alone(tmp_path):
    """A MASK material whose base colour image has no alpha channel: alpha is the factor's."""
    rgb = rgba_checker()[..., :3].copy()
    state = gltf_scene(tmp_path, [pbr("mask", (1, 1, 1, 0.6), True, alphaMode="MASK")], rgb)
    alpha = state.materials["quads.gltf#mask"].alpha
    assert alpha.value == 0.6 and alpha.texture is None


@pytest.mark.parametrize(
    ("fields", "factor", "message"),
    [
        ({"alphaMode": "CUTOUT"}, (1, 1, 1, 1), "alphaMode 'CUTOUT' is not OPAQUE, MASK or BLEND"),
        ({"alphaMode": 3}, (1, 1, 1, 1), "alphaMode 3 is not"),
        ({"alphaMode": "MASK", "alphaCutoff": -0.1}, (1, 1, 1, 1), "alphaCutoff -0.1 is not"),
        ({"alphaMode": "MASK", "alphaCutoff": "half"}, (1, 1, 1, 1), "alphaCutoff 'half'"),
        ({"alphaMode": "BLEND"}, (1, 1, 1, 1.5), r"alpha 1.5 is not in \[0, 1\]"),
        ({"alphaMode": "BLEND"}, (1, 1, 1), "baseColorFactor: expected 4 numbers"),
    ],
)
def test_gltf_bad_alpha_values_are_clear_errors(tmp_path, fields, factor, message):
    with pytest.raises(SceneError, match=message) as error:
        gltf_scene(tmp_path, [pbr("bad", factor, **fields)])
    assert "quads.gltf" in str(error.value) and "'bad'" in str(error.value)


def test_gltf_alpha_warnings(tmp_path):
    """MASK and BLEND warn only where they are ignored: on glass and emitters."""
    cut = gltf_document([pbr("cut", alphaMode="MASK")])
    glass = gltf_document([{**pbr("glass", alphaMode="BLEND"), "extensions": {
        "KHR_materials_transmission": {"transmissionFactor": 1.0}}}])  # fmt: skip
    lamp = gltf_document([{**pbr("lamp", alphaMode="MASK"), "emissiveFactor": [1, 1, 1]}])
    assert not [w for w in feature_warnings(cut) if "alphaMode" in w]
    assert [w for w in feature_warnings(glass) if "alphaMode" in w]
    assert [w for w in feature_warnings(lamp) if "alphaMode" in w]


def test_scene_format_alpha(tmp_path):
    """A scene file's ``alpha``: its texture's alpha channel read linearly, and its checks."""
    Image.fromarray(rgba_checker()).save(tmp_path / "card.png")
    Image.fromarray(rgba_checker()[..., :3].copy()).save(tmp_path / "rgb.png")
    alpha = {"mode": "mask", "cutoff": 0.3, "texture": {"file": "card.png"}}
    rectangle = {"shape": {"type": "rectangle", "size": [2, 2]}, "material": "card"}
    scene = {"camera": {"position": [0, 0, 5], "look_at": [0, 0, 0], "width": 8, "height": 8},
             "materials": {"card": {"alpha": alpha}}, "objects": [rectangle]}  # fmt: skip
    state = load_scene(write_json(tmp_path / "scene.json", scene))
    pixels = state.textures[textures.alpha_image_name("card.png")]
    assert pixels[..., 0].tolist() == rgba_checker()[..., 3].tolist()
    scene["materials"]["card"]["alpha"]["texture"]["file"] = "rgb.png"
    with pytest.raises(SceneError, match=r"rgb\.png: the image has no alpha channel"):
        load_scene(write_json(tmp_path / "scene.json", scene))
    for bad in ({"mode": "cut"}, {"mode": "mask", "cutoff": -1}, {"mode": "blend", "value": 2}):
        with pytest.raises(pydantic.ValidationError):
            fmt.DiffuseMaterial(alpha=bad)
    with pytest.raises(pydantic.ValidationError, match="not supported on emissive"):
        fmt.DiffuseMaterial(emission=(1, 1, 1), alpha={"mode": "blend", "value": 0.5})
    scene["objects"][0]["shape"] = {"type": "box", "size": [1, 1, 1]}
    scene["materials"]["card"]["alpha"]["texture"]["file"] = "card.png"
    with pytest.raises(SceneError, match="alpha texture"):
        load_scene(write_json(tmp_path / "scene.json", scene))

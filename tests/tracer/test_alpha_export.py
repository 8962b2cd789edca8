"""Alpha in the Mitsuba export: a material with ``alpha`` is Mitsuba's ``mask`` rendered by
``volpath``; a blend's opacity is our alpha, a mask's our bilinear alpha thresholded on a finer
grid, which the kernels' own lookup confirms."""

import json
import xml.etree.ElementTree as ET

import numpy as np
import pytest
from numba import njit
from PIL import Image

from tracer.crosscheck.mitsuba_conversions import mask_opacity
from tracer.crosscheck.mitsuba_export import export_scene
from tracer.io.images import read_image
from tracer.scene import format as fmt
from tracer.scene.loader import load_scene
from tracer.shading.textures import (
    ENTRY,
    alpha_image_name,
    bilinear,
    linear_texels,
    texture_table,
)


@njit
def lookup(pixels, info, scale, entry, u, v):
    return bilinear(pixels, info, scale, entry, u, v)


@pytest.mark.parametrize("wrap", ["repeat", "clamp"])
def test_mask_opacity_is_the_kernels_lookup_thresholded(wrap):
    """At every point of the finer grid the opacity is 1 exactly where the kernels' bilinear
    lookup of the alpha texels reaches the cutoff."""
    rng = np.random.default_rng(5)
    alpha = rng.integers(0, 256, (5, 7)).astype(np.uint8)
    grey = np.repeat(alpha[:, :, None], 3, axis=2)
    material = fmt.DiffuseMaterial(alpha={"mode": "mask", "texture": {"file": "a", "wrap": wrap}})
    table = texture_table({alpha_image_name("a"): grey}, [material])
    entry = int(table.alpha[0, ENTRY])
    opacity, k = mask_opacity(linear_texels(alpha).astype(np.float64), wrap, 0.45)
    assert opacity.shape == (5 * k, 7 * k) and k == 8
    for row in range(0, 5 * k, 3):
        for col in range(0, 7 * k, 2):
            u = (col + 0.5) / (7 * k)
            v = 1.0 - (row + 0.5) / (5 * k)
            a = lookup(table.pixels, table.info, table.scale, entry, u, v)[0]
            assert opacity[row, col] == (1.0 if a >= 0.45 else 0.0)


def export_card(tmp_path, alpha: dict):
    Image.fromarray(np.array([[[9, 9, 9, 0], [9, 9, 9, 255]]], np.uint8), "RGBA").save(
        tmp_path / "a.png"
    )
    card = {"name": "card", "shape": {"type": "rectangle"}, "material": "card"}
    scene = {"format": "tilerender/1", "materials": {"card": {"alpha": alpha}},
             "objects": [card]}  # fmt: skip
    (tmp_path / "scene.json").write_text(json.dumps(scene))
    result = export_scene(load_scene(tmp_path / "scene.json"), tmp_path / "out")
    root = ET.fromstring(result.xml)
    return result, root, root.find("bsdf[@id='material-0']")


def opacity_image(tmp_path, mask) -> tuple[ET.Element, np.ndarray]:
    texture = mask.find("texture[@name='opacity']")
    filename = texture.find("string[@name='filename']").get("value")
    return texture, read_image(tmp_path / "out" / filename)


def test_a_blend_is_a_mask_of_our_alpha_under_volpath(tmp_path):
    result, root, mask = export_card(
        tmp_path, {"mode": "blend", "value": 0.5, "texture": {"file": "a.png", "wrap": "clamp"}}
    )
    assert result.integrator == "volpath"
    assert root.find("integrator").get("type") == "volpath"
    assert mask.get("type") == "mask" and mask.find("bsdf").get("type") == "twosided"
    texture, image = opacity_image(tmp_path, mask)
    assert texture.find("string[@name='filter_type']").get("value") == "bilinear"
    np.testing.assert_allclose(image[0, :, 0], [0.0, 0.5])


def test_a_mask_is_thresholded_and_noted(tmp_path):
    result, _, mask = export_card(
        tmp_path, {"mode": "mask", "cutoff": 0.5, "texture": {"file": "a.png", "wrap": "clamp"}}
    )
    texture, image = opacity_image(tmp_path, mask)
    assert texture.find("string[@name='filter_type']").get("value") == "nearest"
    k = image.shape[1] // 2
    np.testing.assert_array_equal(image[0, :, 0], [0.0] * k + [1.0] * k)  # cut at u = 0.5
    assert [d.kind for d in result.deviations if d.feature == "alpha mask 'card'"] == ["proxy"]


def test_alpha_without_texture_is_a_constant_opacity(tmp_path):
    _, _, mask = export_card(tmp_path, {"mode": "mask", "value": 0.3, "cutoff": 0.5})
    assert float(mask.find("float[@name='opacity']").get("value")) == 0.0
    _, _, mask = export_card(tmp_path, {"mode": "blend", "value": 0.3})
    assert float(mask.find("float[@name='opacity']").get("value")) == pytest.approx(0.3)

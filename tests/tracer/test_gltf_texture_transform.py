"""KHR_texture_transform (``tracer.scene.gltf_texture_transform``): the spec's ``T * R * S``,
applied to a mesh's UVs when its file loads, the base colour's transform winning over the
normal map's (with a warning), ``texCoord`` overriding the textureInfo's; a render through a
transform shows the part of the image the transform selects."""

import math

import numpy as np
import pytest
import trimesh
from PIL import Image

from tests.gltf_files import add_node, write_gltf
from tests.tracer.test_mesh_files_warnings import NORMAL_TEXTURE
from tracer.compiled.scene import compile_scene
from tracer.errors import SceneError
from tracer.render import render_lines
from tracer.scene import format as fmt
from tracer.scene.gltf_texture_transform import uv_matrix
from tracer.scene.loader import load_scene, load_warnings

RED, GREEN, BLUE, WHITE = (255, 0, 0), (0, 255, 0), (0, 0, 255), (255, 255, 255)
DIFFER = (
    "KHR_texture_transform approximated: where a material's baseColorTexture and normalTexture "
    "transforms differ, both take the baseColorTexture's"
)


def spec_matrix(offset, rotation, scale) -> np.ndarray:
    """The spec's GLSL, read as column-major mat3s: translation * rotation * scale."""
    c, s = math.cos(rotation), math.sin(rotation)
    translation = np.array([[1, 0, offset[0]], [0, 1, offset[1]], [0, 0, 1]])
    turn = np.array([[c, s, 0], [-s, c, 0], [0, 0, 1]])  # mat3(c, -s, 0, s, c, 0, 0, 0, 1)
    return (translation @ turn @ np.diag([scale[0], scale[1], 1]))[:2]


@pytest.mark.parametrize(
    "offset,rotation,scale", [([0.5, 0.25], 0.0, [1, 1]), ([0, 0], 0.7, [1, 1]),
                              ([0, 1], math.pi / 2, [0.5, 0.5]), ([0.1, -2], -1.2, [3, -0.5])]
)  # fmt: skip
def test_the_matrix_is_the_specs(offset, rotation, scale):
    info = {"extensions": {"KHR_texture_transform": {"offset": offset, "rotation": rotation,
                                                     "scale": scale}}}  # fmt: skip
    np.testing.assert_allclose(uv_matrix(info, "t"), spec_matrix(offset, rotation, scale))
    assert uv_matrix({"index": 0}, "t") is None


def test_the_specs_example_rotates_counter_clockwise():
    """The spec's example (offset [0, 1], rotation pi/2, scale 0.5) uses the lower left
    quadrant of the image: the UV square's corners land on its corners."""
    info = {"extensions": {"KHR_texture_transform": {"offset": [0, 1], "rotation": math.pi / 2,
                                                     "scale": [0.5, 0.5]}}}  # fmt: skip
    corners = np.array([[0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]], float)
    moved = corners @ uv_matrix(info, "t").T
    np.testing.assert_allclose(moved, [[0, 1], [0, 0.5], [0.5, 0.5], [0.5, 1]], atol=1e-15)


def quadrants(size: int = 16) -> Image.Image:
    """Red top left, green top right, blue bottom left, white bottom right."""
    pixels = np.empty((size, size, 3), np.uint8)
    half = size // 2
    pixels[:half, :half], pixels[:half, half:] = RED, GREEN
    pixels[half:, :half], pixels[half:, half:] = BLUE, WHITE
    return Image.fromarray(pixels)


def poster(tmp_path, base=None, normal=None, name="poster", camera=False):
    """A 2x2 quad facing +z with UVs over the whole image, its material's base colour the
    quadrants and (given ``normal``) a normal map, each textureInfo extended by the dicts
    ``base`` and ``normal``; with ``camera``, a camera 3 units in front looking at it."""
    quad = trimesh.Trimesh([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]],
                           [[0, 1, 2], [0, 2, 3]], process=False)  # fmt: skip
    flat = Image.fromarray(np.full((4, 4, 3), (128, 128, 255), np.uint8))
    material = trimesh.visual.material.PBRMaterial(
        name=name, baseColorTexture=quadrants(), metallicFactor=0.0,
        normalTexture=None if normal is None else flat,
    )  # fmt: skip
    quad.visual = trimesh.visual.TextureVisuals(
        uv=[[0, 0], [1, 0], [1, 1], [0, 1]], material=material
    )

    def edit(tree):
        (spec,) = tree["materials"]
        spec["pbrMetallicRoughness"]["baseColorTexture"].update(base or {})
        if normal is not None:
            spec["normalTexture"].update(normal)
        if camera:
            perspective = {"yfov": 0.5, "aspectRatio": 1.0, "znear": 0.1}
            tree["cameras"] = [{"type": "perspective", "perspective": perspective}]
            add_node(tree, {"camera": 0, "translation": [0, 0, 3]})

    return write_gltf(tmp_path / "poster.gltf", edit, quad)


def transform(**values) -> dict:
    return {"extensions": {"KHR_texture_transform": values}}


def test_uvs_are_moved_as_the_spec_says(tmp_path):
    """The loaded UVs are the file's (glTF's v down) through T * R * S, back in our v up."""
    values = {"offset": [0.25, -0.5], "rotation": 0.4, "scale": [2.0, 0.5]}
    plain = load_scene(poster(tmp_path))
    (mesh,) = [m for key, m in plain.meshes.items() if key.startswith("poster.gltf")]
    moved = load_scene(poster(tmp_path, base=transform(**values)))
    (moved_mesh,) = [m for key, m in moved.meshes.items() if key.startswith("poster.gltf")]
    gltf_uv = np.column_stack([mesh.uvs[:, 0], 1 - mesh.uvs[:, 1], np.ones(len(mesh.uvs))])
    expected = gltf_uv @ spec_matrix(values["offset"], values["rotation"], values["scale"]).T
    np.testing.assert_allclose(moved_mesh.uvs[:, 0], expected[:, 0], atol=1e-6)
    np.testing.assert_allclose(moved_mesh.uvs[:, 1], 1 - expected[:, 1], atol=1e-6)
    assert load_warnings(tmp_path / "poster.gltf") == []


def test_a_render_shows_the_quadrant_the_transform_selects(tmp_path):
    """Scale 0.5 and offset (0.5, 0) select the image's top right quadrant (glTF's v runs
    down): the albedo across the middle of the quad is its green, where without the transform
    the four quadrants meet."""
    selected = poster(tmp_path, base=transform(offset=[0.5, 0], scale=[0.5, 0.5]), camera=True)
    state = load_scene(selected)
    scene = compile_scene(state)
    camera = fmt.override(state.camera, width=8, height=8)
    settings = fmt.override(state.render, spp=4, integrator="albedo")
    albedo = render_lines(scene, 0, 8, camera, settings, threads=1).rgb.reshape(8, 8, 3)
    np.testing.assert_allclose(albedo[2:6, 2:6], np.broadcast_to([0, 1, 0], (4, 4, 3)), atol=1e-3)
    whole = load_scene(poster(tmp_path, camera=True))
    plain = render_lines(compile_scene(whole), 0, 8, camera, settings, threads=1).rgb
    plain = plain.reshape(8, 8, 3)
    np.testing.assert_allclose(plain[1, 1], [1, 0, 0], atol=1e-3)  # red, top left
    np.testing.assert_allclose(plain[6, 6], [1, 1, 1], atol=1e-3)  # white, bottom right


def test_the_base_colours_transform_wins_and_differing_ones_warn(tmp_path):
    """A normal map with another transform (or one where the base colour has none): the UVs
    take the base colour's, and it warns; the same transform on both is exact and silent."""
    base = transform(offset=[0.5, 0])
    both = load_scene(poster(tmp_path, base=base, normal=transform(scale=[2, 2])))
    (uvs,) = [m.uvs for key, m in both.meshes.items() if key.startswith("poster.gltf")]
    np.testing.assert_allclose(uvs[0], [0.5, 0.0])
    mikktspace = f"poster.gltf: {NORMAL_TEXTURE}"
    assert load_warnings(tmp_path / "poster.gltf") == [mikktspace, f"poster.gltf: {DIFFER}"]
    poster(tmp_path, base=base, normal=base)
    assert load_warnings(tmp_path / "poster.gltf") == [mikktspace]
    normal_only = load_scene(poster(tmp_path, normal=transform(offset=[0.25, 0])))
    (uvs,) = [m.uvs for key, m in normal_only.meshes.items() if key.startswith("poster.gltf")]
    np.testing.assert_allclose(uvs[0], [0.0, 0.0])  # the base colour's: none
    assert load_warnings(tmp_path / "poster.gltf") == [mikktspace, f"poster.gltf: {DIFFER}"]


def test_tex_coord_overrides(tmp_path):
    """texCoord 1 on the textureInfo brought back to 0 by the transform reads TEXCOORD_0
    exactly (no warning); a transform asking for set 1 warns that set 0 is used."""
    poster(tmp_path, base={"texCoord": 1, **transform(offset=[0.5, 0], texCoord=0)})
    assert load_warnings(tmp_path / "poster.gltf") == []
    poster(tmp_path, base=transform(offset=[0.5, 0], texCoord=1))
    (warning,) = load_warnings(tmp_path / "poster.gltf")
    assert "UV sets after TEXCOORD_0 ignored" in warning


def test_an_unnamed_material_keeps_its_uvs_and_warns(tmp_path):
    path = poster(tmp_path, base=transform(offset=[0.5, 0]), name="")
    state = load_scene(path)
    (uvs,) = [m.uvs for key, m in state.meshes.items() if key.startswith("poster.gltf")]
    np.testing.assert_allclose(uvs[0], [0.0, 0.0])
    (warning,) = load_warnings(path)
    assert "KHR_texture_transform ignored on materials without a name" in warning


@pytest.mark.parametrize(
    "values", [{"offset": [1]}, {"scale": [1, "2"]}, {"rotation": None}, {"offset": [1, 1e400]}]
)
def test_malformed_transforms_are_scene_errors(tmp_path, values):
    with pytest.raises(SceneError, match=r"poster\.gltf: material 'poster'"):
        load_scene(poster(tmp_path, base=transform(**values)))

"""Tangent-space normal maps (docs/materials.md, "Normal maps"): the normal they give against
the frame worked out by hand, through instances; read linearly; switched by the effect plan;
stable in the furnace; no leaks; clear errors."""

import dataclasses

import numpy as np
import pytest
from PIL import Image

from tests.helpers import compile_dict, mean_and_error, render_passes, tiny_scene
from tests.tracer.test_shading_normals import first_hits
from tracer.compiled.scene import compile_scene
from tracer.errors import SceneError
from tracer.integrators.flags import NORMAL_MAPS, SHADOW_TERMINATOR
from tracer.render import effect_plan, render_image
from tracer.scene import format as fmt

TILT = (0.5, -0.3, 0.81)
"""The map's vector in the tangent frame (x along +u, y along +v, z along the normal)."""


def texel_of(vector) -> np.ndarray:
    return np.rint((np.asarray(vector) / np.linalg.norm(vector) + 1.0) * 127.5).astype(np.uint8)


def decoded(texel, strength=1.0) -> np.ndarray:
    v = 2.0 * texel.astype(np.float64) / 255.0 - 1.0
    return v * [strength, strength, 1.0]


def map_scene(tmp_path, strength=1.0, rotate=(0.0, 0.0, 0.0), kind="static", texel=None):
    """A floor (u along +x, v along -z, facing +y) with a constant normal map, seen from
    above, under the tiny scene's lamp."""
    texel = texel_of(TILT) if texel is None else texel
    Image.fromarray(np.tile(texel, (4, 4, 1))).save(tmp_path / "tilt.png")
    data = tiny_scene()
    data["camera"].update(width=24, height=18, position=[0.3, 3.0, 1.0], look_at=[0, 0, 0])
    data["materials"]["grey"]["normal_map"] = {"file": "tilt.png", "strength": strength}
    data["objects"][0].update(kind=kind, transform={"rotate": list(rotate)})
    data["objects"][0]["shape"]["size"] = 3
    del data["objects"][1]  # the cube: the floor alone
    return compile_dict(data, tmp_path)


def expected_normal(texel, strength, rotate):
    """The mapped normal worked out by hand: tangent +x (dp/du), bitangent -z (dp/dv), normal
    +y, all rotated like the floor."""
    x, y, z = decoded(texel, strength)
    n = x * np.array([1.0, 0, 0]) + y * np.array([0, 0, -1.0]) + z * np.array([0, 1.0, 0])
    matrix = fmt.Transform(rotate=rotate).to_matrix()[:3, :3]
    n = matrix @ n
    return n / np.linalg.norm(n)


@pytest.mark.parametrize("kind", ["static", "rigid"])
@pytest.mark.parametrize("strength, rotate", [(1.0, (0, 0, 0)), (0.5, (0, 0, 0)),
                                              (1.0, (10, 35, -8))])  # fmt: skip
def test_the_normal_is_the_maps_vector_in_the_tangent_frame(tmp_path, kind, strength, rotate):
    """Wherever a camera ray hits the floor, the normal AOV is the map's (8-bit) vector in the
    floor's tangent frame, strength applied, rotated with the floor, baked or instanced."""
    scene = compile_dict_map = map_scene(tmp_path, strength, rotate, kind)
    assert effect_plan(compile_dict_map, scene.render).flags & NORMAL_MAPS
    normal, _, hit, _ = first_hits(scene)
    assert hit.sum() > 100
    expected = expected_normal(texel_of(TILT), strength, rotate)
    np.testing.assert_allclose(normal[hit], np.broadcast_to(expected, normal[hit].shape),
                               atol=2e-6)  # fmt: skip


def test_normal_maps_are_read_linearly(tmp_path):
    """The map's texels are c / 255, not sRGB-decoded like base-colour textures."""
    scene = map_scene(tmp_path)
    table = scene.textures
    row = table.normal_map[scene.material_names.index("grey")]
    first = table.info[row, 0]
    np.testing.assert_array_equal(table.pixels[first], texel_of(TILT) / np.float32(255.0))


def test_effect_plan_and_switching_normal_maps_off(tmp_path):
    """Without a map the plan has no normal maps; switched off, the mapped floor renders bit for
    bit as the plain one; on, it differs; depth reads no normals."""
    scene = map_scene(tmp_path)
    data = tiny_scene()
    assert not effect_plan(compile_dict(data), compile_dict(data).render).flags & NORMAL_MAPS
    assert effect_plan(scene, scene.render).flags & SHADOW_TERMINATOR
    depth = fmt.override(scene.render, integrator="depth")
    assert not effect_plan(scene, depth).flags & NORMAL_MAPS
    off = fmt.override(scene.render, effects={"normal_maps": False})
    assert not effect_plan(scene, off).flags & (NORMAL_MAPS | SHADOW_TERMINATOR)
    plain = map_scene(tmp_path, strength=0.0)  # strength 0: the map's z only, the normal itself
    flat = render_image(scene, None, settings=off)[0]
    assert not np.array_equal(flat, render_image(scene, None)[0])
    normal, _, hit, _ = first_hits(plain)
    np.testing.assert_allclose(normal[hit], np.broadcast_to([0, 1.0, 0], normal[hit].shape),
                               atol=1e-12)  # fmt: skip


@pytest.mark.parametrize("tilt, floor", [((0.3, 0.1, 0.95), 0.9), ((0.9, 0.2, 0.4), 0.65)],
                         ids=["18-degrees", "66-degrees"])  # fmt: skip
def test_a_normal_mapped_floor_in_the_white_furnace(tmp_path, tilt, floor):
    """A white floor whose map tilts every normal by the same angle, under a sky of 1: finite,
    non-negative, never above 1 (four standard errors). It loses light: reflections the tilted
    normal sends below the floor end, and the terminator falloff fades grazing light (measured:
    0.920 at 18 degrees, 0.686 at 66; without the falloff 0.978 and 0.751)."""
    scene = map_scene(tmp_path, texel=texel_of(tilt))
    normal_map = scene.state.materials["grey"].normal_map
    white = fmt.DiffuseMaterial(reflectance=(1.0, 1.0, 1.0), normal_map=normal_map)
    materials = {**scene.state.materials, "grey": white, "lamp": white}
    state = dataclasses.replace(scene.state, sky=fmt.ConstantSky(radiance=(1.0, 1.0, 1.0)),
                                materials=materials)  # fmt: skip
    furnace = compile_scene(state)
    passes = render_passes(furnace, 4, 16, max_depth=16, rr_depth=16)
    assert np.isfinite(passes).all() and (passes >= 0).all()
    mean, se = mean_and_error(passes)
    assert np.all(mean <= 1.0 + 4.0 * se), (mean, se)
    assert np.all(mean > floor), mean


def test_a_normal_map_needs_uvs(tmp_path):
    Image.fromarray(np.full((2, 2, 3), 128, np.uint8)).save(tmp_path / "n.png")
    data = tiny_scene()
    data["materials"]["grey"]["normal_map"] = {"file": "n.png"}
    with pytest.raises(SceneError, match="has a normal map, but the mesh has no UVs"):
        compile_dict(data, tmp_path)

"""Shading normals (docs/materials.md, "Shading normals"): interpolated where a mesh has vertex
normals, carried through instances and the static bake, shown by the normal output and AOV,
switched by the effect plan, stable in the white furnace, and leaving flat scenes' bits alone."""

import numpy as np
import pytest

from tests.helpers import SCENES, compile_dict, mean_and_error, render_passes, tiny_scene
from tests.tracer.test_furnace import furnace
from tracer.compiled.scene import compile_scene
from tracer.integrators import aov
from tracer.integrators.flags import SHADING_NORMALS, SHADOW_TERMINATOR
from tracer.render import effect_plan, render_image, render_pixels
from tracer.scene import format as fmt
from tracer.scene.loader import scene_from_file_model
from tracer.scene.ops import Commit, ReplaceMesh, UpdateVertices, apply_commit

CENTRE = (0.0, 0.7, 0.0)


def ball_scene(smooth: bool, kind: str = "static", scale=(1.0, 1.0, 1.0), subdivisions=2,
               width=48, height=36, **render) -> dict:  # fmt: skip
    """A sphere on a floor under the tiny scene's lamp, framed by the camera."""
    data = tiny_scene()
    data["camera"].update(width=width, height=height, position=[0, 1.2, 3.0], look_at=[0, 0.7, 0])
    data["render"].update(render)
    data["objects"][1] = {
        "name": "ball",
        "shape": {"type": "sphere", "radius": 0.6, "subdivisions": subdivisions, "smooth": smooth},
        "material": "grey",
        "kind": kind,
        "transform": {"translate": list(CENTRE), "scale": list(scale)},
    }
    return data


def first_hits(scene, **changes):
    """The AOVs of one sample per pixel: (normal, position, hit mask, object ids)."""
    camera = scene.camera
    settings = fmt.override(scene.render, spp=1, aovs=True, **changes)
    out = render_pixels(scene, 0, camera.width * camera.height, camera, settings).aov
    hit = out[:, aov.ALPHA] == 1.0
    normal = out[:, aov.NORMAL : aov.NORMAL + 3].astype(np.float64)
    position = out[:, aov.POSITION : aov.POSITION + 3].astype(np.float64)
    return normal, position, hit, out[:, aov.OBJECT_ID]


def ellipsoid_normal(position, scale):
    """The exact normal of the sphere scaled by ``scale`` about ``CENTRE`` at ``position``."""
    local = (position - CENTRE) / np.asarray(scale)
    n = local / np.asarray(scale)
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def angle_deg(a, b):
    cos = np.clip(np.einsum("ij,ij->i", a, b), -1.0, 1.0)
    return np.degrees(np.arccos(cos))


@pytest.mark.parametrize("kind", ["static", "rigid"])
@pytest.mark.parametrize("scale", [(1.0, 1.0, 1.0), (1.6, 0.7, 1.0)])
def test_normal_aov_follows_the_curved_surface(kind, scale):
    """On a smooth icosphere (320 triangles), baked static or instanced, uniformly or
    non-uniformly scaled, the normal AOV is within 1.5 degrees of the exact surface's normal;
    the same sphere shading flat is off by more than 4 degrees somewhere (the test can fail)."""
    errors = {}
    for smooth in (False, True):
        scene = compile_dict(ball_scene(smooth, kind, scale))
        normal, position, hit, ids = first_hits(scene)
        on_ball = hit & (ids == 1)
        assert on_ball.sum() > 200
        errors[smooth] = angle_deg(normal[on_ball], ellipsoid_normal(position[on_ball], scale))
    assert errors[True].max() < 1.5, errors[True].max()
    assert errors[False].max() > 4.0, errors[False].max()


def test_normal_integrator_shows_the_shading_normal():
    """The debug ``normal`` output maps the shading normal (0.5 n + 0.5), as the AOV does."""
    scene = compile_dict(ball_scene(True, spp=1))
    normal, _, hit, _ = first_hits(scene)
    image = render_image(scene, None, settings=fmt.override(scene.render, integrator="normal"))[0]
    mapped = image.reshape(-1, 3)[hit]
    assert np.allclose(mapped, 0.5 * normal[hit] + 0.5, atol=1e-6)


def test_effect_plan_runs_shading_normals_only_where_meshes_have_them():
    """A scene with a smooth mesh plans the effect; a flat one does not, nor an output that
    reads no normal; switched off, the smooth sphere renders exactly as the flat one."""
    smooth = compile_dict(ball_scene(True, spp=2))
    flat = compile_dict(ball_scene(False, spp=2))
    assert effect_plan(smooth, smooth.render).flags & SHADING_NORMALS
    assert not effect_plan(flat, flat.render).flags & SHADING_NORMALS
    depth = fmt.override(smooth.render, integrator="depth")
    assert not effect_plan(smooth, depth).flags & SHADING_NORMALS
    off = fmt.override(smooth.render, effects={"shading_normals": False})
    assert np.array_equal(render_image(smooth, None, settings=off)[0], render_image(flat, None)[0])
    assert not np.array_equal(render_image(smooth, None)[0], render_image(flat, None)[0])


def test_smooth_and_flat_spheres_agree_where_the_surface_is_the_same():
    """Smooth shading moves light within the sphere, not onto the floor: the floor's pixels
    agree within noise, and the image's total is within 2% of the flat sphere's."""
    results = {}
    for smooth in (False, True):
        scene = compile_dict(ball_scene(smooth, spp=16, subdivisions=3))
        passes = render_passes(scene, 4, 16)
        ids = first_hits(scene)[3]
        results[smooth] = passes, ids
    floor = results[False][1] == 0
    means = {k: mean_and_error(p.reshape(4, -1, 3)[:, floor][:, :, None, :], axis=(1, 2))
             for k, (p, _) in results.items()}  # fmt: skip
    (m0, e0), (m1, e1) = means[False], means[True]
    assert np.all(np.abs(m0 - m1) < 4.0 * np.hypot(e0, e1) + 1e-4), (m0, m1, e0, e1)
    total = {k: p.mean() for k, (p, _) in results.items()}
    assert abs(total[True] / total[False] - 1.0) < 0.02, total


@pytest.mark.parametrize(
    "material, subdivisions, floor",
    [
        ({"reflectance": [1.0, 1.0, 1.0]}, 1, 0.97),
        ({"reflectance": [1.0, 1.0, 1.0]}, 3, 0.995),
        ({"type": "dielectric", "ior": 1.5}, 1, 0.985),
        ({"type": "dielectric", "ior": 1.5}, 3, 0.998),
        ({"type": "plastic", "reflectance": [1.0, 1.0, 1.0], "roughness": 0.0}, 3, 0.995),
    ],
    ids=["diffuse-80", "diffuse-1280", "glass-80", "glass-1280", "plastic-1280"],
)
def test_smooth_sphere_in_the_white_furnace(material, subdivisions, floor):
    """Shading normals never create energy, NaN or negative radiance: under a sky of 1 the
    image is at most 1 within four standard errors and every sample is finite and >= 0. They
    lose a little (samples the shading normal sends through the geometric surface, and the
    terminator's falloff), more on coarser meshes: at least ``floor`` remains (measured:
    0.982 / 0.998 diffuse, 0.989 / 0.999 glass, 0.997 plastic)."""
    sphere = {"shape": {"type": "sphere", "radius": 1.0, "subdivisions": subdivisions,
                        "smooth": True}, "material": "m"}  # fmt: skip
    scene = furnace(material, [sphere], max_depth=64, rr_depth=64)
    passes = render_passes(scene, 4, 16)
    assert np.isfinite(passes).all() and (passes >= 0.0).all()
    mean, se = mean_and_error(passes)
    assert np.all(mean <= 1.0 + 4.0 * se), (mean, se)
    assert np.all(mean > floor), mean


def leaning_floor_scene(normals: bool):
    """A floor whose vertex normals lean 60 degrees toward +x, seen from above, lit only from
    below by a lamp off to the +x side: light that reaches the top is a leak."""
    data = tiny_scene()
    data["camera"].update(width=32, height=24, position=[0, 3.0, 2.0], look_at=[0, 0, 0])
    data["render"].update(spp=16)
    data["materials"]["lamp"]["two_sided"] = True
    data["objects"] = [
        {"name": "floor", "shape": {"type": "plane", "size": 4}, "material": "grey"},
        {"name": "lamp", "shape": {"type": "rectangle", "size": [1, 1]}, "material": "lamp",
         "transform": {"translate": [2.5, -0.6, 0], "rotate": [0, 90, 0]}},
    ]  # fmt: skip
    state = scene_from_file_model(fmt.SceneFile.model_validate(data), SCENES)
    if normals:
        key = state.nodes[0].mesh
        mesh = state.meshes[key]
        lean = np.tile([np.sin(np.radians(60)), np.cos(np.radians(60)), 0.0], (4, 1))
        op = ReplaceMesh(mesh=key, vertices=mesh.vertices, faces=mesh.faces, normals=lean)
        state = apply_commit(state, Commit(state.version + 1, (op,)))
    return compile_scene(state)


def test_no_light_leaks_through_a_surface_whose_normals_lean_toward_the_light():
    """Lit only from below, the top of a floor whose shading normals lean toward the lamp stays
    exactly black: the geometric normal decides which side light arrives from. The lamp does
    light the underside (seen from below, the test can fail)."""
    scene = leaning_floor_scene(normals=True)
    assert effect_plan(scene, scene.render).flags & SHADING_NORMALS
    assert render_image(scene, None)[0].max() == 0.0
    below = fmt.override(scene.camera, position=(0.0, -3.0, 2.0))
    assert render_image(scene, below)[0].max() > 0.0


def test_the_terminator_falloff_is_its_own_effect():
    """Planned with shading normals where lights are sampled, not without them nor for the
    ``normal`` output; switched off, the smooth sphere gets brighter (the falloff only takes
    light away), the floor does not change by more than noise, and no pixel turns negative."""
    scene = compile_dict(ball_scene(True, spp=32, subdivisions=1))
    flags = effect_plan(scene, scene.render).flags
    assert flags & SHADOW_TERMINATOR
    normal = fmt.override(scene.render, integrator="normal")
    assert not effect_plan(scene, normal).flags & SHADOW_TERMINATOR
    flat = compile_dict(ball_scene(False, spp=2))
    assert not effect_plan(flat, flat.render).flags & SHADOW_TERMINATOR
    off = fmt.override(scene.render, effects={"shadow_terminator": False})
    assert not effect_plan(scene, off).flags & SHADOW_TERMINATOR
    ids = first_hits(scene)[3].reshape(scene.camera.height, scene.camera.width)
    with_falloff = render_passes(scene, 4, 32)
    without = render_passes(scene, 4, 32, effects={"shadow_terminator": False})
    assert (with_falloff >= 0).all() and (without >= 0).all()
    ball = ids == 1
    m_on, e_on = mean_and_error(with_falloff[:, ball][:, :, None, :], axis=(1, 2))
    m_off, e_off = mean_and_error(without[:, ball][:, :, None, :], axis=(1, 2))
    assert np.all(m_off - m_on > 4.0 * np.hypot(e_on, e_off)), (m_on, m_off, e_on, e_off)


def test_a_deformed_smooth_mesh_refits_with_normals_that_follow_it():
    """update_vertices on a deformable smooth sphere: the refitted scene (compiled from the
    previous one) has the normals of a scene compiled from scratch, bit for bit, and they are
    the stretched sphere's smooth normals, not the old ones."""
    data = ball_scene(True, kind="deformable", subdivisions=2)
    state = scene_from_file_model(fmt.SceneFile.model_validate(data), SCENES)
    before = compile_scene(state)
    key = state.nodes[1].mesh
    stretched = state.meshes[key].vertices * [1.3, 0.8, 1.0]
    op = UpdateVertices(mesh=key, vertices=stretched)
    moved = apply_commit(state, Commit(state.version + 1, (op,)))
    refitted = compile_scene(moved, before)
    fresh = compile_scene(moved)
    a, b = first_hits(refitted), first_hits(fresh)
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[2], b[2])
    normal, position, hit, ids = a
    ball = hit & (ids == 1)
    exact = ellipsoid_normal(position[ball], (1.3, 0.8, 1.0))
    assert angle_deg(normal[ball], exact).max() < 3.0

"""Integrators: ``direct`` is the path of two vertices; NEE-only (Whitted), BSDF-only and MIS
estimate the same direct light, and the path tracer without MIS the same image as with it;
Russian roulette leaves the expected image unchanged; Whitted recursion through mirrors and
glass; ambient occlusion against an analytic value; the debug outputs (albedo, normal, depth,
cost)."""

import math
from pathlib import Path

import numpy as np
import pytest

from tests.helpers import CORNELL, compile_dict, mean_and_error, render_passes, two_planes
from tests.stats import pass_statistics, welch_pixel_test
from tracer.compiled.scene import compile_scene
from tracer.integrators import path as integrator
from tracer.integrators import surface as surface_integrators
from tracer.integrators import vertex
from tracer.integrators.effects import EffectPlan, effect_plan
from tracer.integrators.flags import (
    LIGHT_SAMPLES,
    MATERIAL_BUILD,
    MATERIAL_EFFECTS,
    NO_MIS,
    SHADOWS,
)
from tracer.io.heatmap import cost_heatmap
from tracer.render import render_image
from tracer.scene.format import override
from tracer.scene.loader import load_scene

SCENES = Path(__file__).resolve().parents[2] / "scenes"


@pytest.fixture(scope="module")
def cornell():
    scene = compile_scene(load_scene(CORNELL))
    return scene, override(scene.camera, width=32, height=32)


def passes_with_plan(scene, camera, settings, plan, passes, spp):
    """Independent passes rendered under an explicit effect plan, (K, H, W, 3)."""
    from tracer.render import render_lines

    settings = override(settings, spp=spp)
    return np.stack(
        [
            render_lines(
                scene, 0, camera.height, camera, settings, sample_start=k * spp, plan=plan
            ).rgb
            for k in range(passes)
        ]
    ).astype(np.float64)


def agree(a: np.ndarray, b: np.ndarray) -> None:
    """Two sets of passes estimate the same image: image means within 4 combined standard
    errors, and the Sidak-corrected per-pixel Welch test accepts >= 99% of pixels."""
    mean_a, se_a = mean_and_error(a)
    mean_b, se_b = mean_and_error(b)
    z = (mean_a - mean_b) / np.sqrt(se_a**2 + se_b**2)
    assert np.all(np.abs(z) < 4.0), z
    result = welch_pixel_test(*pass_statistics(a), *pass_statistics(b))
    assert result.accepted_fraction >= 0.99


def test_direct_is_the_two_vertex_path(cornell):
    scene, camera = cornell
    settings = override(scene.render, spp=4)
    direct, _ = render_image(scene, camera, override(settings, integrator="direct"))
    path, _ = render_image(scene, camera, override(settings, max_depth=2))
    assert direct.tobytes() == path.tobytes()


def test_nee_bsdf_and_mis_agree(cornell):
    """Direct light three ways: light samples only (the Whitted kernel on Lambertian surfaces),
    BSDF samples only (the path kernel without light samples), and both with MIS (direct).
    BSDF samples rarely find the small light, so their passes take 256 samples per pixel: with
    fewer, pass means are too skewed for the per-pixel t-test."""
    scene, camera = cornell
    settings = override(scene.render, max_depth=2, seed=2)
    # Different seeds: the tests assume independent estimates.
    mis = render_passes(scene, 12, 8, camera, max_depth=2)
    nee = render_passes(scene, 12, 8, camera, integrator="whitted", seed=1)
    plan = effect_plan(scene, settings)
    bsdf_only = EffectPlan(plan.flags & ~(LIGHT_SAMPLES | SHADOWS), {})
    bsdf = passes_with_plan(scene, camera, settings, bsdf_only, 12, 256)
    agree(mis, nee)
    agree(mis, bsdf)


def test_path_without_mis_agrees_with_mis(cornell):
    """The path tracer with light samples and no MIS (``NO_MIS``: emitters that
    BSDF-sampled rays hit count only after delta bounces and for camera rays) estimates the
    same image as with MIS, at every depth; it is a different estimator (the images differ)."""
    scene, camera = cornell
    settings = override(scene.render, seed=3)
    plan = effect_plan(scene, settings)
    no_mis = EffectPlan(plan.flags | NO_MIS, {})
    mis = render_passes(scene, 12, 8, camera)
    nee = passes_with_plan(scene, camera, settings, no_mis, 12, 8)
    agree(mis, nee)
    same_seed = passes_with_plan(scene, camera, settings, plan, 1, 8)
    assert same_seed[0].tobytes() != nee[0].tobytes()


def test_path_without_mis_under_a_sky():
    """The sky and sun branch: a white diffuse sphere under a white sky is invisible to the
    path tracer (a furnace: every pixel is 1 in expectation) with MIS and without it."""
    scene = furnace({"reflectance": [1, 1, 1]}, "path")
    settings = override(scene.render, spp=8)
    plan = effect_plan(scene, settings)
    for flags in (plan.flags, plan.flags | NO_MIS):
        passes = passes_with_plan(scene, scene.camera, settings, EffectPlan(flags, {}), 8, 8)
        mean, se = mean_and_error(passes)
        assert np.all(np.abs(mean - 1.0) < 4 * se + 1e-6), (flags, mean, se)


def test_material_build_switch_changes_only_the_build(cornell):
    """``MATERIAL_BUILD`` runs a Lambertian plan in the kernel build with the material
    dispatch: another kernel, the same pixels bit for bit."""
    scene, camera = cornell
    settings = override(scene.render, spp=2)
    plan = effect_plan(scene, settings)
    assert not plan.flags & MATERIAL_EFFECTS
    switched = EffectPlan(plan.flags | MATERIAL_BUILD, {})
    assert integrator.kernel_for(switched.flags) is not integrator.kernel_for(plan.flags)
    light = render_image(scene, camera, settings, plan=plan)[0]
    general = render_image(scene, camera, settings, plan=switched)[0]
    assert light.tobytes() == general.tobytes()


def test_a_missing_strategy_is_caught(cornell):
    """Negative control: BSDF sampling without its emission hits (light samples switched off,
    and the emission of hit lights only seen directly) loses the direct light and is rejected."""
    scene, camera = cornell
    mis = render_passes(scene, 6, 8, camera, max_depth=2, seed=1)
    plan = EffectPlan(effect_plan(scene, scene.render).flags & ~LIGHT_SAMPLES, {})
    broken = passes_with_plan(scene, camera, override(scene.render, max_depth=1), plan, 6, 8)
    with pytest.raises(AssertionError):
        agree(mis, broken)


def test_russian_roulette_is_unbiased(cornell):
    """Roulette from the first bounce (rr_depth 1) and none at all (rr_depth = max_depth) give
    the same expected image."""
    scene, camera = cornell
    early = render_passes(scene, 12, 8, camera, rr_depth=1)
    none = render_passes(scene, 12, 8, camera, rr_depth=8, seed=1)
    agree(early, none)


ROULETTE_VARIANCE_LIMIT = 1.2
"""Variance with roulette over without, at equal samples, in cornell-spheres (docs/robustness.md:
about 1.1 when the survival probability sees through glass, 1.25-1.35 when it does not)."""


def test_roulette_does_not_cut_paths_for_being_inside_glass():
    """Inside a dielectric the throughput carries the 1 / eta^2 of entering it; roulette must
    judge the path by what it carries once out, or it kills bright paths in glass. Its variance
    stays close to no roulette at all, and its mean is the same."""
    scene = compile_scene(load_scene(SCENES / "cornell-spheres" / "scene.json"))
    camera = override(scene.camera, width=64, height=64)
    with_roulette = render_passes(scene, 16, 64, camera)
    without = render_passes(scene, 16, 64, camera, rr_depth=scene.render.max_depth + 1)
    agree(with_roulette, without)
    ratio = with_roulette.var(axis=0, ddof=1).mean() / without.var(axis=0, ddof=1).mean()
    assert ratio <= ROULETTE_VARIANCE_LIMIT, ratio


def furnace(material, integrator_name):
    return compile_dict(
        {
            "camera": {
                "position": [0, 0.5, 4],
                "look_at": [0, 0, 0],
                "vfov_deg": 36,
                "width": 16,
                "height": 16,
            },
            "render": {"spp": 4, "max_depth": 64, "rr_depth": 64, "integrator": integrator_name},
            "sky": {"radiance": [1.0, 1.0, 1.0]},
            "materials": {"m": material},
            "objects": [{"shape": {"type": "sphere", "subdivisions": 3}, "material": "m"}],
        }
    )


def test_whitted_follows_delta_lobes():
    """Whitted recursion: a mirror and a glass sphere under a white sky are invisible (every
    path follows delta lobes out to the sky)."""
    mirror = render_passes(furnace({"type": "mirror"}, "whitted"), 1, 4)
    assert np.all(mirror == 1.0)
    glass = render_passes(furnace({"type": "dielectric"}, "whitted"), 1, 8)
    assert abs(glass.mean() - 1.0) < 5e-3


def test_whitted_has_no_indirect_light():
    """A white diffuse sphere under a white sky: Whitted shows its direct light (1, the sky is
    all direct for a convex object) and stops there: the same as the path tracer, but a
    concave scene would differ (checked below on the Cornell box)."""
    mean, se = mean_and_error(render_passes(furnace({"reflectance": [1, 1, 1]}, "whitted"), 8, 8))
    assert np.all(np.abs(mean - 1.0) < 4 * se), (mean, se)


def test_whitted_is_darker_than_path_in_the_cornell_box(cornell):
    scene, camera = cornell
    whitted = render_passes(scene, 4, 8, camera, integrator="whitted").mean()
    path = render_passes(scene, 4, 8, camera).mean()
    assert whitted < 0.8 * path


def test_ambient_occlusion_between_two_planes():
    """Under a parallel plane at height h, occlusion rays of length L escape when
    cos(theta) < h / L: with cosine-weighted directions, a fraction (h / L)^2."""
    diagonal = math.sqrt(40.0**2 + 1.0 + 40.0**2)
    for length in (2.0, 4.0):
        scene = two_planes(8, length / diagonal, 8, spp=16)
        mean, se = mean_and_error(render_passes(scene, 8, 16))
        expected = (1.0 / length) ** 2
        assert np.all(np.abs(mean - expected) < 4 * se + 1e-9), (length, mean, se)
    # rays shorter than the gap never hit the ceiling
    open_sky = two_planes(8, 0.5 / diagonal, 8, spp=16)
    assert np.all(render_passes(open_sky, 1, 4) == 1.0)


def test_debug_outputs():
    """Albedo is the reflectance exactly, the normal facing the camera maps to 0.5 n + 0.5,
    depth is the distance along the camera ray, misses are 0."""
    data = {
        "camera": {
            "position": [0, 3, 0],
            "look_at": [0, 0, 0],
            "up": [0, 0, -1],
            "vfov_deg": 2.0,
            "width": 4,
            "height": 4,
        },
        "render": {"spp": 4},
        "materials": {
            "m": {"reflectance": [0.2, 0.4, 0.6]},
            "glass": {"type": "dielectric"},
        },
        "objects": [{"shape": {"type": "plane", "size": 10.0}, "material": "m"}],
    }
    albedo = render_passes(compile_dict(data), 1, 4, integrator="albedo")[0]
    np.testing.assert_allclose(albedo, np.broadcast_to([0.2, 0.4, 0.6], albedo.shape), rtol=1e-6)
    normal = render_passes(compile_dict(data), 1, 4, integrator="normal")[0]
    np.testing.assert_allclose(normal, np.broadcast_to([0.5, 1.0, 0.5], normal.shape), atol=1e-7)
    depth = render_passes(compile_dict(data), 1, 16, integrator="depth")[0]
    assert np.all(np.abs(depth - 3.0) < 3.0 * (1.0 / math.cos(math.radians(1.5)) - 1.0) + 1e-6)
    glass = {**data, "objects": [{**data["objects"][0], "material": "glass"}]}
    white = render_passes(compile_dict(glass), 1, 1, integrator="albedo")[0]
    assert np.all(white == 1.0)
    away = {**data, "camera": {**data["camera"], "look_at": [0, 6, 0]}}
    assert np.all(render_passes(compile_dict(away), 1, 1, integrator="depth") == 0.0)


def test_cost_heat_map(cornell):
    """The cost output is the path kernel's per-pixel work through a fixed ramp: the same for
    any split of the frame, blue for cheap pixels, toward red for expensive ones."""
    scene, camera = cornell
    settings = override(scene.render, spp=2)
    from tracer.render import render_lines

    lines = render_lines(scene, 0, camera.height, camera, override(settings, integrator="cost"))
    whole, _ = render_image(scene, camera, override(settings, integrator="cost"))
    assert lines.rgb.tobytes() == whole.tobytes()
    assert np.all((whole >= 0.0) & (whole <= 1.0))
    ramp = cost_heatmap(np.array([0, 10, 1000, 10**9]), 1)
    np.testing.assert_array_equal(ramp[0], [0, 0, 1])
    np.testing.assert_array_equal(ramp[-1], [1, 0, 0])
    assert ramp[1][1] > 0.0 and ramp[2][0] > ramp[1][0]


def test_lens_dimension_is_shared():
    """The surface kernels place the lens sample where the path vertex code reserves it."""
    assert surface_integrators.LENS_DIM == vertex.LENS_DIM == vertex.DIMS_PER_VERTEX


@pytest.mark.parametrize("detail", ["textures", "shading_normals", "normal_maps"])
def test_surface_detail_runs_the_material_build(detail):
    """Textures, vertex normals and normal maps are compiled only into the build with the
    material dispatch: a Lambertian plan that needs one runs that build, one without runs the
    lean build."""
    from tracer.integrators.flags import AREA_LIGHTS, EFFECTS

    lean = AREA_LIGHTS | LIGHT_SAMPLES | SHADOWS
    assert integrator.build_for(lean) == (False, False)
    assert integrator.build_for(lean | EFFECTS[detail]) == (True, False)

"""The ray counter (``RenderedLines.rays``): every ray a kernel traces, counted exactly where the
count is known, and the same however a frame is split.

Exact counts come from scenes where every path is known in advance: a closed box lit by a point
light (every ray hits a wall, every light sample is in front of the wall and casts a shadow ray,
nothing a ray can hit emits), a mirror or glass floor under a sky that fills the view (one
reflected or refracted ray escapes to the sky), and two parallel planes for ambient occlusion.
"""

import numpy as np
import pytest

from tests.helpers import CORNELL, compile_dict, two_planes
from tracer.compiled.scene import compile_scene
from tracer.integrators.effects import EffectPlan, effect_plan
from tracer.integrators.flags import EMITTER_HITS, LIGHT_SAMPLES, NO_MIS, SHADOWS
from tracer.render import render_image, render_lines
from tracer.scene.format import override
from tracer.scene.loader import load_scene

SPP = 3


def rays_per_sample(scene, settings=None, plan=None, camera=None) -> np.ndarray:
    """Rays traced per line, (H,), at ``SPP`` samples, divided by the line's camera samples
    (one line per call)."""
    camera = camera or scene.camera
    settings = override(settings or scene.render, spp=SPP)
    lines = [
        render_lines(scene, y, y + 1, camera, settings, plan=plan, threads=1)
        for y in range(camera.height)
    ]
    return np.concatenate([line.rays for line in lines]) / (camera.width * SPP)


@pytest.fixture(scope="module")
def lit_box():
    """The camera inside a closed grey box (two-sided walls) with a point light in it."""
    return compile_dict(
        {
            "camera": {"position": [0, 0, 1.5], "look_at": [0, 0, 0], "width": 6, "height": 5},
            "render": {"spp": SPP},
            "lights": [{"type": "point", "position": [0.3, 1.2, -0.4], "intensity": [5, 5, 5]}],
            "materials": {"grey": {"reflectance": [0.5, 0.5, 0.5]}},
            "objects": [{"shape": {"type": "box", "size": [4, 4, 4]}, "material": "grey"}],
        }
    )


@pytest.fixture(scope="module")
def cornell():
    scene = compile_scene(load_scene(CORNELL))
    return scene, override(scene.camera, width=16, height=12)


def no_roulette(scene, depth: int, **changes):
    return override(scene.render, max_depth=depth, rr_depth=depth, **changes)


def test_lit_box_plan(lit_box):
    """The premises of the counts below: light samples and shadows, nothing to hit that emits."""
    flags = effect_plan(lit_box, lit_box.render).flags
    assert flags & LIGHT_SAMPLES and flags & SHADOWS
    assert not flags & EMITTER_HITS


@pytest.mark.parametrize("depth", [1, 2, 3, 5, 8])
def test_path_in_a_closed_box(lit_box, depth):
    """Without Russian roulette every path reaches ``depth`` vertices: a camera or bounce ray
    to each of the first ``depth - 1``, and one shadow ray from each; the last vertex's ray,
    which could only find emission, is never traced. Depth 1 is the camera ray alone."""
    expected = 1 if depth == 1 else 2 * (depth - 1)
    rays = rays_per_sample(lit_box, no_roulette(lit_box, depth))
    assert np.all(rays == expected)


@pytest.mark.parametrize("depth", [2, 5])
def test_shadow_rays_once_per_light_sample(lit_box, depth):
    """Switching shadows off removes exactly one ray per light sample; dropping light samples
    too (the sweep's ``path-bsdf``) leaves the camera and bounce rays; without MIS the same rays
    as with it."""
    settings = no_roulette(lit_box, depth)
    plan = effect_plan(lit_box, settings)
    unshadowed = rays_per_sample(lit_box, override(settings, effects={"shadows": False}))
    assert np.all(unshadowed == (depth - 1))
    bsdf_only = EffectPlan(plan.flags & ~(LIGHT_SAMPLES | SHADOWS), {})
    assert np.all(rays_per_sample(lit_box, settings, bsdf_only) == (depth - 1))
    no_mis = EffectPlan(plan.flags | NO_MIS, {})
    assert np.all(rays_per_sample(lit_box, settings, no_mis) == 2 * (depth - 1))


def test_every_effect_traces_the_last_ray(lit_box):
    """Without the effect plan, emission might be hit, so the last vertex's ray is traced too."""
    depth = 4
    rays = rays_per_sample(lit_box, no_roulette(lit_box, depth, effect_plan=False))
    assert np.all(rays == (2 * (depth - 1) + 1))


def test_direct_and_whitted_in_a_closed_box(lit_box):
    """``direct`` and Whitted at a diffuse wall: the camera ray and one shadow ray."""
    for integrator in ("direct", "whitted"):
        settings = override(lit_box.render, integrator=integrator)
        assert np.all(rays_per_sample(lit_box, settings) == 2), integrator


def test_roulette_traces_fewer_rays(lit_box):
    """Roulette from the second vertex ends some paths early, never before the first vertex's
    light sample."""
    depth = 8
    full = rays_per_sample(lit_box, no_roulette(lit_box, depth))
    early = rays_per_sample(lit_box, override(no_roulette(lit_box, depth), rr_depth=1))
    assert np.all(early >= 2) and np.all(early <= full)
    assert early.sum() < full.sum()


def specular_floor(material: dict) -> object:
    """A large floor of ``material`` filling the view of a camera looking down, under a sky."""
    return compile_dict(
        {
            "camera": {
                "position": [0, 3, 0],
                "look_at": [0, 0, 0],
                "up": [0, 0, -1],
                "vfov_deg": 10.0,
                "width": 5,
                "height": 4,
            },
            "render": {"spp": SPP, "max_depth": 6},
            "sky": {"radiance": [1.0, 1.0, 1.0]},
            "materials": {"m": material},
            "objects": [{"shape": {"type": "plane", "size": 10.0}, "material": "m"}],
        }
    )


@pytest.mark.parametrize("material", [{"type": "mirror"}, {"type": "dielectric"}])
@pytest.mark.parametrize("integrator", ["whitted", "path"])
def test_reflected_and_refracted_rays(material, integrator):
    """A delta surface takes no light sample: the camera ray, then one reflected (or refracted)
    ray that escapes to the sky."""
    scene = specular_floor(material)
    rays = rays_per_sample(scene, override(scene.render, integrator=integrator))
    assert np.all(rays == 2)


@pytest.mark.parametrize("ao_samples", [1, 4, 9])
def test_ambient_occlusion_rays(ao_samples):
    """Each camera sample that hits casts ``ao_samples`` occlusion rays; the debug outputs trace
    the camera ray alone; a camera ray that misses casts nothing more."""
    scene = two_planes(ao_samples, 0.1, 4)
    assert np.all(rays_per_sample(scene) == (1 + ao_samples))
    for output in ("albedo", "normal", "depth"):
        settings = override(scene.render, integrator=output)
        assert np.all(rays_per_sample(scene, settings) == 1), output
    away = override(scene.camera, look_at=[0.0, 0.5, -1.0], up=[0.0, 1.0, 0.0], vfov_deg=1.0)
    assert np.all(rays_per_sample(scene, camera=away) == 1)


def test_camera_rays_only_at_depth_one(cornell):
    """A path of one vertex traces only the camera ray, hit or miss."""
    scene, camera = cornell
    rays = rays_per_sample(scene, override(scene.render, max_depth=1), camera=camera)
    assert np.all(rays == 1)


@pytest.mark.parametrize("integrator", ["path", "whitted", "ao"])
def test_counts_do_not_depend_on_the_split(cornell, integrator):
    """Line ranges and thread counts change nothing; disjoint sample ranges add up; the counts
    lie between the camera rays and the most a path can trace."""
    scene, camera = cornell
    settings = override(scene.render, spp=4, integrator=integrator)
    whole = render_lines(scene, 0, camera.height, camera, settings, threads=2).rays
    ranges = [(0, 1), (1, 5), (5, 6), (6, camera.height)]
    parts = [render_lines(scene, a, b, camera, settings, threads=1).rays for a, b in ranges]
    assert np.array_equal(np.concatenate(parts), whole)
    first = render_lines(scene, 0, camera.height, camera, override(settings, spp=2), threads=2)
    second = render_lines(
        scene, 0, camera.height, camera, override(settings, spp=2), sample_start=2, threads=2
    )
    assert np.array_equal(first.rays + second.rays, whole)
    collected = []
    render_image(scene, camera, settings, lines_per_call=5, on_lines=collected.append)
    assert np.array_equal(np.concatenate([p.rays for p in collected]), whole)
    per_sample = {"path": 2 * scene.render.max_depth, "whitted": 2, "ao": 1 + settings.ao_samples}
    pixels = camera.width * settings.spp
    assert np.all(whole >= pixels) and np.all(whole <= pixels * per_sample[integrator])
    assert whole.dtype == np.int64 and whole.shape == (camera.height,)
    assert whole.sum() > camera.height * pixels  # more than the camera rays

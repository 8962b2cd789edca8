"""Pixel runs (``render_pixels``): any split of a frame into runs [p0, p1) of its row-major
pixels (inside one line, across line ends, single pixels) gives the pixels ``render_image``
gives, bit for bit, with per-pixel cost and rays that sum to ``render_lines``' per-line values;
runs outside the frame are refused."""

from itertools import pairwise

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tests.helpers import compile_dict
from tracer.integrators.effects import EffectPlan, effect_plan
from tracer.integrators.flags import MATERIAL_EFFECTS, NO_MIS, SUN
from tracer.render import render_image, render_lines, render_pixels
from tracer.scene.format import override

WIDTH, HEIGHT, SPP = 13, 7, 2
"""A width that is no multiple of ``PIXEL_BLOCK``, so runs and blocks end in mid-line."""
PIXELS = WIDTH * HEIGHT

VARIANTS = ["path", "path-no-mis", "whitted", "direct", "ao", "albedo", "cost", "materials"]
"""Integrators on the Cornell box (Lambertian, area lights), ``path-no-mis`` with the plan's
``NO_MIS`` switch, and ``materials``: the path kernel's build with the BSDFs and the other lights
(glass, a mirror, a sun, a sky and a point light)."""


def materials_scene():
    """A small scene that needs the path kernel's build with materials and non-area lights."""
    return compile_dict(
        {
            "camera": {"position": [0, 1, 4], "look_at": [0, 0.5, 0], "width": WIDTH,
                       "height": HEIGHT},
            "render": {"spp": SPP, "max_depth": 5},
            "sky": {"radiance": [0.2, 0.25, 0.3]},
            "lights": [
                {"type": "sun", "to_sun": [0.3, 1, 0.2], "irradiance": [2, 2, 2]},
                {"type": "point", "position": [1, 2, 1], "intensity": [3, 3, 3]},
            ],
            "materials": {
                "floor": {"reflectance": [0.6, 0.6, 0.6]},
                "glass": {"type": "dielectric", "ior": 1.5, "absorption": [0.5, 0.2, 0.1]},
                "gold": {"type": "conductor", "reflectance": [1.0, 0.78, 0.34],
                         "roughness": 0.3},
            },
            "objects": [
                {"shape": {"type": "plane", "size": 8.0}, "material": "floor"},
                {"shape": {"type": "sphere", "radius": 0.5, "subdivisions": 2},
                 "material": "glass", "transform": {"translate": [-0.6, 0.5, 0.0]}},
                {"shape": {"type": "sphere", "radius": 0.5, "subdivisions": 2},
                 "material": "gold", "transform": {"translate": [0.6, 0.5, 0.0]}},
            ],
        }
    )  # fmt: skip


@pytest.fixture(scope="module", params=VARIANTS)
def view(request, cornell):
    """(scene, camera, settings, plan) of one variant, and the reference: ``render_image``'s
    rgb and ``render_lines``' per-line cost and rays (one call per line)."""
    variant = request.param
    scene = materials_scene() if variant == "materials" else cornell
    camera = override(scene.camera, width=WIDTH, height=HEIGHT)
    integrator = {"path-no-mis": "path", "materials": "path"}.get(variant, variant)
    settings_ = override(scene.render, spp=SPP, integrator=integrator)
    plan = effect_plan(scene, settings_)
    if variant == "path-no-mis":
        plan = EffectPlan(plan.flags | NO_MIS, {})
    if variant == "materials":
        assert plan.flags & MATERIAL_EFFECTS and plan.flags & SUN
    rgb, line_cost = render_image(scene, camera, settings_, plan=plan, threads=1)
    lines = [render_lines(scene, y, y + 1, camera, settings_, plan=plan) for y in range(HEIGHT)]
    line_rays = np.concatenate([line.rays for line in lines])
    assert np.array_equal(np.concatenate([line.cost for line in lines]), line_cost)
    return scene, camera, settings_, plan, rgb, line_cost, line_rays


def render_runs(view, cuts, threads=1):
    """The frame rendered as the pixel runs between ``cuts``, stitched into (rgb (H, W, 3),
    cost (H, W), rays (H, W))."""
    scene, camera, settings_, plan = view[:4]
    runs = [
        render_pixels(scene, p0, p1, camera, settings_, plan=plan, threads=threads)
        for p0, p1 in pairwise([0, *cuts, PIXELS])
    ]
    for run in runs:
        n = run.p1 - run.p0
        assert run.rgb.shape == (n, 3) and run.rgb.dtype == np.float32
        assert run.cost.shape == run.rays.shape == (n,)
        assert run.cost.dtype == run.rays.dtype == np.int64
        assert run.spp == SPP and run.seconds >= 0.0
    rgb = np.concatenate([run.rgb for run in runs]).reshape(HEIGHT, WIDTH, 3)
    cost = np.concatenate([run.cost for run in runs]).reshape(HEIGHT, WIDTH)
    rays = np.concatenate([run.rays for run in runs]).reshape(HEIGHT, WIDTH)
    return rgb, cost, rays


def assert_matches(view, rgb, cost, rays):
    reference, line_cost, line_rays = view[4:]
    assert np.isfinite(reference).all() and reference.std() > 0.0  # not a blank frame
    assert np.array_equal(rgb, reference)
    assert np.array_equal(cost.sum(axis=1), line_cost)
    assert np.array_equal(rays.sum(axis=1), line_rays)
    assert (rays > 0).all()  # every pixel traced its camera rays


@pytest.mark.parametrize(
    "cuts",
    [
        [],  # the whole frame in one run
        [5, 6, 13, 20, 40, 41, 90],  # runs inside one line, across line ends, single pixels
        list(range(1, PIXELS)),  # every pixel alone
    ],
    ids=["one-run", "mixed", "single-pixels"],
)
def test_pixel_runs_are_bit_identical(view, cuts):
    """Fixed splits, on one thread and on two."""
    for threads in (1, 2):
        assert_matches(view, *render_runs(view, cuts, threads))


@settings(max_examples=6)
@given(
    cuts=st.sets(st.integers(1, PIXELS - 1), max_size=12).map(sorted),
    threads=st.integers(1, 3),
)
def test_any_pixel_split_is_bit_identical(view, cuts, threads):
    """Any partition of the pixels into runs, on any thread count."""
    assert_matches(view, *render_runs(view, cuts, threads))


def test_whole_lines_are_the_line_aligned_run(cornell):
    """``render_lines`` is the run [y0 W, y1 W): the same pixels, and its per-line counts are
    the run's per-pixel counts summed over each line."""
    camera = override(cornell.camera, width=WIDTH, height=HEIGHT)
    settings_ = override(cornell.render, spp=SPP)
    lines = render_lines(cornell, 2, 5, camera, settings_)
    run = render_pixels(cornell, 2 * WIDTH, 5 * WIDTH, camera, settings_)
    assert np.array_equal(lines.rgb, run.rgb.reshape(3, WIDTH, 3))
    assert np.array_equal(lines.cost, run.cost.reshape(3, WIDTH).sum(axis=1))
    assert np.array_equal(lines.rays, run.rays.reshape(3, WIDTH).sum(axis=1))


@pytest.mark.parametrize(
    ("p0", "p1", "message"),
    [
        (-1, 5, "not inside"),
        (5, 5, "not inside"),
        (6, 5, "not inside"),
        (0, PIXELS + 1, "not inside"),
        (PIXELS, PIXELS + 1, "not inside"),
        (0.0, 5, "integer"),
        (0, "5", "integer"),
    ],
)
def test_bad_runs_are_refused(cornell, p0, p1, message):
    camera = override(cornell.camera, width=WIDTH, height=HEIGHT)
    with pytest.raises(ValueError, match=message):
        render_pixels(cornell, p0, p1, camera)


def test_bad_frame_and_sample_start_are_refused(cornell):
    camera = override(cornell.camera, width=WIDTH, height=HEIGHT)
    for changes in ({"frame": -1}, {"sample_start": -1}):
        with pytest.raises(ValueError, match="non-negative"):
            render_pixels(cornell, 0, 5, camera, **changes)

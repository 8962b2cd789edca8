"""Public entry points: render a pixel run or a line range, or a whole image with progress.

``render.integrator`` picks the kernel: ``path``, ``direct`` (a path of two vertices),
``whitted`` and ``cost`` (the path kernel's work as a heat map, ``tracer.io.heatmap``) run
``tracer.integrators.path`` under the effect plan (``tracer.integrators.effects``); ``ao``,
``albedo``,
``normal`` and ``depth`` run ``tracer.integrators.surface``.

``render_pixels`` renders any run [p0, p1) of a frame's pixels in row-major order, and
``render_lines`` the line-aligned run [y0 * W, y1 * W): what a tracer runs for its share of a
frame. ``render_image`` loops over line chunks in Python (one jitted call each), so progress and
cancellation stay outside the kernel.
"""

import numbers
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from tracer import config
from tracer.compiled.arrays import SceneArrays
from tracer.compiled.scene import CompiledScene
from tracer.integrators import effects
from tracer.integrators.effects import EffectPlan, effect_plan
from tracer.integrators.path import PATH, WHITTED, kernel_for, render_pixels_specialised
from tracer.integrators.surface import OUTPUTS, render_surface
from tracer.io.heatmap import cost_heatmap
from tracer.kernel.threads import run_parts
from tracer.maths import portable
from tracer.scene import format as fmt
from tracer.shading.camera import camera_array
from tracer.shading.lights import light_arrays, scene_fields

SAMPLES_PER_CALL = 1 << 18
"""Samples per kernel call in ``render_image``: enough that the threads' shares even out
(smaller calls measured 5% slower on two threads), few enough for a smooth progress bar."""


@dataclass
class RenderedLines:
    """Lines [y0, y1): ``rgb`` float32 (y1-y0, W, 3) linear radiance, mean of ``spp`` samples;
    ``cost`` int64 (y1-y0,) work per line (BVH node visits plus triangle tests); ``rays`` int64
    (y1-y0,) rays traced per line (camera, continuation, shadow and occlusion rays)."""

    y0: int
    y1: int
    rgb: np.ndarray
    cost: np.ndarray
    rays: np.ndarray
    spp: int
    seconds: float


@dataclass
class RenderedPixels:
    """The pixel run [p0, p1): pixels in row-major order (index ``y * W + x``), n = p1 - p0 of
    them. ``rgb`` float32 (n, 3) as ``RenderedLines.rgb``; ``cost`` int64 (n,) and ``rays``
    int64 (n,) the work and the rays of each pixel (what ``RenderedLines`` sums per line)."""

    p0: int
    p1: int
    rgb: np.ndarray
    cost: np.ndarray
    rays: np.ndarray
    spp: int
    seconds: float


def arrays_for_plan(scene: CompiledScene, plan: EffectPlan) -> SceneArrays:
    """The scene's arrays with only the lights the plan keeps (the same arrays when it keeps
    every light the scene has)."""
    kinds = plan.light_kinds()
    present = {int(k) for k in scene.lights.kind[scene.lights.weight > 0.0]}
    if present <= kinds:
        return scene.arrays
    light = light_arrays(scene.lights, kinds)
    return scene.arrays._replace(**scene_fields(light))


def render_lines(
    scene: CompiledScene,
    y0: int,
    y1: int,
    camera: fmt.Camera | None = None,
    settings: fmt.RenderSettings | None = None,
    frame: int = 0,
    sample_start: int = 0,
    threads: int | None = None,
    plan: EffectPlan | None = None,
    specialised: bool | None = None,
) -> RenderedLines:
    """Render lines [y0, y1) of a frame: the pixel run [y0 * W, y1 * W) (:func:`render_pixels`).

    Pixels take samples [sample_start, sample_start + settings.spp); two calls with disjoint
    sample ranges give independent estimates that average to the larger render. ``threads``
    defaults to every CPU this process may use. ``plan`` is the effect plan (default: the one
    ``tracer.integrators.effects.effect_plan`` makes of the scene and settings); ``specialised``
    runs a kernel compiled for that plan instead of the one with runtime flags (default:
    ``config.SPECIALISED_KERNELS``).
    """
    camera = camera or scene.camera
    if not 0 <= y0 < y1 <= camera.height:
        raise ValueError(f"line range [{y0}, {y1}) is not inside [0, {camera.height})")
    width = camera.width
    run = render_pixels(
        scene, y0 * width, y1 * width, camera, settings, frame, sample_start, threads, plan,
        specialised,
    )  # fmt: skip
    lines = y1 - y0
    return RenderedLines(
        y0,
        y1,
        run.rgb.reshape(lines, width, 3),
        run.cost.reshape(lines, width).sum(axis=1),
        run.rays.reshape(lines, width).sum(axis=1),
        run.spp,
        run.seconds,
    )


def render_pixels(
    scene: CompiledScene,
    p0: int,
    p1: int,
    camera: fmt.Camera | None = None,
    settings: fmt.RenderSettings | None = None,
    frame: int = 0,
    sample_start: int = 0,
    threads: int | None = None,
    plan: EffectPlan | None = None,
    specialised: bool | None = None,
) -> RenderedPixels:
    """Render the pixel run [p0, p1) of a frame (row-major pixel indices ``y * W + x``; a run
    may start and end anywhere in a line). Every pixel gets the bits it gets in any other split
    of the frame; the other arguments are as for :func:`render_lines`.
    """
    camera = camera or scene.camera
    settings = settings or scene.render
    if not (isinstance(p0, numbers.Integral) and isinstance(p1, numbers.Integral)):
        raise ValueError(f"pixel run [{p0!r}, {p1!r}) needs integer bounds")
    p0, p1 = int(p0), int(p1)
    width, height = camera.width, camera.height
    if not 0 <= p0 < p1 <= width * height:
        raise ValueError(
            f"pixel run [{p0}, {p1}) is not inside [0, {width * height}) (a {width}x{height} frame)"
        )
    if frame < 0 or sample_start < 0:
        raise ValueError("frame and sample_start must be non-negative")
    if plan is None:
        plan = effect_plan(scene, settings)
    cam = camera_array(
        np.asarray(camera.position) - scene.origin,
        np.asarray(camera.look_at) - scene.origin,
        camera.up,
        camera.vfov_deg,
        width,
        height,
        camera.aperture_radius,
        camera.focus_distance,
    )
    # The kernels write rows of the lines the run touches; the run is a slice of them.
    y_first = p0 // width
    rows = (p1 - 1) // width + 1 - y_first
    rgb = np.empty((rows, width, 3), np.float32)
    cost = np.empty((rows, width), np.int64)
    rays = np.empty((rows, width), np.int64)
    start = time.perf_counter()
    if settings.integrator in OUTPUTS:
        surface_args = (
            scene.arrays,
            cam,
            width,
            height,
            p0,
            p1,
            sample_start,
            settings.spp,
            settings.seed,
            frame,
            OUTPUTS[settings.integrator],
            settings.ao_samples,
            settings.ao_distance * scene_diagonal(scene),
            bool(plan.flags & effects.TEXTURES),
        )

        def work(part: int, parts: int) -> None:
            stack_node = np.empty(config.TRAVERSAL_STACK_SIZE, np.int32)
            stack_t = np.empty(config.TRAVERSAL_STACK_SIZE, np.float64)
            render_surface(*surface_args, part, parts, stack_node, stack_t, rgb, cost, rays)

    else:
        max_depth = settings.max_depth
        path = settings.integrator in ("path", "cost")
        if settings.integrator == "direct" or (path and not plan.flags & effects.INDIRECT):
            max_depth = min(max_depth, 2)
        mode = WHITTED if settings.integrator == "whitted" else PATH
        args = (
            arrays_for_plan(scene, plan),
            cam,
            width,
            height,
            p0,
            p1,
            sample_start,
            settings.spp,
            max_depth,
            settings.rr_depth,
            settings.seed,
            frame,
            1.0 - config.SHADOW_EPSILON,
            mode,
            plan.flags,
        )
        if specialised is None:
            specialised = config.SPECIALISED_KERNELS
        kernel = render_pixels_specialised if specialised else kernel_for(plan.flags)

        def work(part: int, parts: int) -> None:
            stack_node = np.empty(config.TRAVERSAL_STACK_SIZE, np.int32)
            stack_t = np.empty(config.TRAVERSAL_STACK_SIZE, np.float64)
            kernel(*args, part, parts, stack_node, stack_t, rgb, cost, rays)

    run_parts(work, threads)
    run = slice(p0 - y_first * width, p1 - y_first * width)
    pixel_cost = cost.reshape(-1)[run]
    if settings.integrator == "cost":
        pixel_rgb = cost_heatmap(pixel_cost, settings.spp)
    else:
        pixel_rgb = rgb.reshape(-1, 3)[run]
    seconds = time.perf_counter() - start
    return RenderedPixels(
        p0, p1, pixel_rgb, pixel_cost, rays.reshape(-1)[run], settings.spp, seconds
    )


def scene_diagonal(scene: CompiledScene) -> float:
    """Length of the diagonal of the scene's bounding box (world units)."""
    return portable.norm(np.subtract(scene.stats.bounds_max, scene.stats.bounds_min))


def render_image(
    scene: CompiledScene,
    camera: fmt.Camera | None = None,
    settings: fmt.RenderSettings | None = None,
    frame: int = 0,
    sample_start: int = 0,
    lines_per_call: int | None = None,
    threads: int | None = None,
    on_lines: Callable[[RenderedLines], None] | None = None,
    plan: EffectPlan | None = None,
    specialised: bool | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Render a whole frame; returns ``(rgb float32 (H, W, 3), cost int64 (H,))``.

    ``on_lines`` is called after each chunk (for progress bars); ``plan`` and ``specialised``
    as for :func:`render_lines`.
    """
    camera = camera or scene.camera
    settings = settings or scene.render
    if lines_per_call is None:
        lines_per_call = max(
            1, min(camera.height, SAMPLES_PER_CALL // max(1, camera.width * settings.spp))
        )
    image = np.empty((camera.height, camera.width, 3), np.float32)
    cost = np.empty(camera.height, np.int64)
    if plan is None:
        plan = effect_plan(scene, settings)
    for y0 in range(0, camera.height, lines_per_call):
        y1 = min(camera.height, y0 + lines_per_call)
        part = render_lines(
            scene, y0, y1, camera, settings, frame, sample_start, threads, plan, specialised
        )
        image[y0:y1] = part.rgb
        cost[y0:y1] = part.cost
        if on_lines is not None:
            on_lines(part)
    return image, cost

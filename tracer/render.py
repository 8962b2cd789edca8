"""Public entry points: render a pixel run or a line range, or a whole image with progress.

``render.integrator`` picks the kernel through the registry (``tracer.integrators.registry``),
under the effect plan (``tracer.integrators.effects``).

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

from tracer.compiled.scene import CompiledScene
from tracer.integrators import flags
from tracer.integrators.aov import world_positions
from tracer.integrators.effects import EffectPlan, effect_plan
from tracer.integrators.kernel_choice import chosen_kernel
from tracer.integrators.pixels import pixel_run, trace_run
from tracer.integrators.registry import REGISTRY
from tracer.io.heatmap import cost_heatmap
from tracer.scene import format as fmt

SAMPLES_PER_CALL = 1 << 18
"""Samples per kernel call in ``render_image``: enough that the threads' shares even out
(smaller calls measured 5% slower on two threads), few enough for a smooth progress bar."""


@dataclass
class RenderedLines:
    """Lines [y0, y1): ``rgb`` float32 (y1-y0, W, 3) linear radiance, mean of ``spp`` samples;
    ``cost`` int64 (y1-y0,) work per line (BVH node visits plus triangle tests); ``rays`` int64
    (y1-y0,) rays traced per line (camera, continuation, shadow and occlusion rays); ``aov``
    float32 (y1-y0, W, ``aov.CHANNELS``) when the settings render AOVs, else None."""

    y0: int
    y1: int
    rgb: np.ndarray
    cost: np.ndarray
    rays: np.ndarray
    spp: int
    seconds: float
    aov: np.ndarray | None = None


@dataclass
class RenderedPixels:
    """The pixel run [p0, p1): pixels in row-major order (index ``y * W + x``), n = p1 - p0 of
    them. ``rgb`` float32 (n, 3) as ``RenderedLines.rgb``; ``cost`` int64 (n,) and ``rays``
    int64 (n,) the work and the rays of each pixel (what ``RenderedLines`` sums per line);
    ``aov`` float32 (n, ``aov.CHANNELS``) when the settings render AOVs
    (``tracer.integrators.aov``, positions in world space), else None."""

    p0: int
    p1: int
    rgb: np.ndarray
    cost: np.ndarray
    rays: np.ndarray
    spp: int
    seconds: float
    aov: np.ndarray | None = None


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
    counts: np.ndarray | None = None,
) -> RenderedLines:
    """Render lines [y0, y1) of a frame: the pixel run [y0 * W, y1 * W) (:func:`render_pixels`).

    Pixels take samples [sample_start, sample_start + settings.spp); two calls with disjoint
    sample ranges give independent estimates that average to the larger render. ``threads``
    defaults to every CPU this process may use. ``plan`` is the effect plan (default: the one
    ``tracer.integrators.effects.effect_plan`` makes of the scene and settings). ``counts``
    (one per pixel of the frame, each in [1, settings.spp]) gives pixel ``i`` only the samples
    [sample_start, sample_start + counts[i]) (adaptive sampling); None gives each all of them.
    """
    camera = camera or scene.camera
    if not 0 <= y0 < y1 <= camera.height:
        raise ValueError(f"line range [{y0}, {y1}) is not inside [0, {camera.height})")
    width = camera.width
    run = render_pixels(
        scene, y0 * width, y1 * width, camera, settings, frame, sample_start, threads, plan, counts
    )
    lines = y1 - y0
    return RenderedLines(
        y0,
        y1,
        run.rgb.reshape(lines, width, 3),
        run.cost.reshape(lines, width).sum(axis=1),
        run.rays.reshape(lines, width).sum(axis=1),
        run.spp,
        run.seconds,
        None if run.aov is None else run.aov.reshape(lines, width, -1),
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
    counts: np.ndarray | None = None,
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
    integrator = REGISTRY[settings.integrator]
    start = time.perf_counter()
    aovs = settings.renders_aovs
    run_flags = plan.flags | (flags.AOVS if aovs else 0)
    run = pixel_run(scene, camera, settings, p0, p1, frame, sample_start, run_flags, counts)
    kernel = chosen_kernel(settings, plan.flags)
    rgb, cost, rays, aov = trace_run(kernel, integrator.arguments(scene, run), run, threads, aovs)
    if aov is not None:
        world_positions(aov, scene.origin)
    if integrator.heat_map:
        rgb = cost_heatmap(cost, settings.spp)
    seconds = time.perf_counter() - start
    return RenderedPixels(p0, p1, rgb, cost, rays, settings.spp, seconds, aov)


def chunk_lines(camera: fmt.Camera, settings: fmt.RenderSettings) -> int:
    """Lines ``render_image`` renders per kernel call: about ``SAMPLES_PER_CALL`` samples."""
    return max(1, min(camera.height, SAMPLES_PER_CALL // max(1, camera.width * settings.spp)))


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
) -> tuple[np.ndarray, np.ndarray]:
    """Render a whole frame; returns ``(rgb float32 (H, W, 3), cost int64 (H,))``.

    ``on_lines`` is called after each chunk (for progress bars); ``plan`` as for
    :func:`render_lines`; ``lines_per_call`` defaults to :func:`chunk_lines`.
    """
    camera = camera or scene.camera
    settings = settings or scene.render
    chunk = chunk_lines(camera, settings) if lines_per_call is None else lines_per_call
    image = np.empty((camera.height, camera.width, 3), np.float32)
    cost = np.empty(camera.height, np.int64)
    if plan is None:
        plan = effect_plan(scene, settings)
    for y0 in range(0, camera.height, chunk):
        y1 = min(camera.height, y0 + chunk)
        part = render_lines(scene, y0, y1, camera, settings, frame, sample_start, threads, plan)
        image[y0:y1] = part.rgb
        cost[y0:y1] = part.cost
        if on_lines is not None:
            on_lines(part)
    return image, cost

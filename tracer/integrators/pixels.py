"""The pixel loop every integrator shares: a run of a frame's pixels, split over threads.

A kernel renders pixel blocks ``part, part + parts, ...`` of the pixel run [p0, p1) (pixels in
row-major order, index ``y * W + x``) into rows of the lines the run touches; ``trace_run``
gives each thread its traversal stacks, runs the parts and slices the run out of those rows.
"""

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from tracer import config
from tracer.compiled.scene import CompiledScene
from tracer.integrators.aov import CHANNELS
from tracer.kernel.threads import run_parts
from tracer.scene import format as fmt
from tracer.shading.camera import camera_array

NO_COUNTS = np.zeros(0, np.int32)
"""The kernels' ``counts`` of a uniform render: every pixel takes ``spp`` samples."""


@dataclass(frozen=True)
class PixelRun:
    """What a kernel needs of a render besides the scene: the camera (``camera_array``), the
    frame's size, the pixel run [p0, p1), the first sample, the settings, the frame, the
    effect plan's flags and the samples of each pixel of the frame (``counts``, int32; empty:
    ``settings.spp`` each)."""

    camera: np.ndarray
    width: int
    height: int
    p0: int
    p1: int
    sample_start: int
    settings: fmt.RenderSettings
    frame: int
    flags: int
    counts: np.ndarray = field(default_factory=lambda: NO_COUNTS)


def pixel_run(
    scene: CompiledScene,
    camera: fmt.Camera,
    settings: fmt.RenderSettings,
    p0: int,
    p1: int,
    frame: int,
    sample_start: int,
    flags: int,
    counts: np.ndarray | None = None,
) -> PixelRun:
    """The run [p0, p1) of a frame seen by ``camera`` (in world units; the kernels work in the
    scene's render space, about ``scene.origin``); ``counts``: samples per pixel of the frame
    (:func:`check_counts`), None for ``settings.spp`` each."""
    cam = camera_array(
        np.asarray(camera.position) - scene.origin,
        np.asarray(camera.look_at) - scene.origin,
        camera.up,
        camera.vfov_deg,
        camera.width,
        camera.height,
        camera.aperture_radius,
        camera.focus_distance,
    )
    if counts is None:
        counts = NO_COUNTS
    else:
        counts = check_counts(counts, camera.width * camera.height, settings.spp)
    return PixelRun(
        cam, camera.width, camera.height, p0, p1, sample_start, settings, frame, flags, counts
    )


def check_counts(counts: np.ndarray, pixels: int, spp: int) -> np.ndarray:
    """``counts`` as a writable int32 array (the kernels' type) of one count in [1, ``spp``]
    for each of a frame's ``pixels``, or ValueError."""
    counts = np.array(counts, dtype=np.int32).reshape(-1)
    if counts.shape != (pixels,):
        raise ValueError(f"expected a sample count for each of {pixels} pixels, got {counts.size}")
    if pixels and not (1 <= int(counts.min()) and int(counts.max()) <= spp):
        raise ValueError(f"sample counts must lie in [1, spp = {spp}]")
    return counts


def trace_run(
    kernel: Callable[..., None],
    arguments: tuple,
    run: PixelRun,
    threads: int | None = None,
    aovs: bool = False,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    """Call ``kernel(*arguments, part, parts, stack_node, stack_t, out_rgb, out_cost, out_rays,
    out_aov)`` on ``threads`` threads (default: every CPU this process may use); returns the
    run's pixels: ``rgb`` float32 (n, 3), ``cost`` int64 (n,), ``rays`` int64 (n,) and, with
    ``aovs`` (the plan's ``flags.AOVS``), ``aov`` float32 (n, ``aov.CHANNELS``) or None;
    n = p1 - p0."""
    width = run.width
    y_first = run.p0 // width
    rows = (run.p1 - 1) // width + 1 - y_first
    rgb = np.empty((rows, width, 3), np.float32)
    cost = np.empty((rows, width), np.int64)
    rays = np.empty((rows, width), np.int64)
    # Without AOVs the kernel never writes out_aov: one pixel's worth keeps its type.
    aov = np.empty((rows, width, CHANNELS) if aovs else (1, 1, CHANNELS), np.float32)

    def work(part: int, parts: int) -> None:
        stack_node = np.empty(config.TRAVERSAL_STACK_SIZE, np.int32)
        stack_t = np.empty(config.TRAVERSAL_STACK_SIZE, np.float64)
        kernel(*arguments, part, parts, stack_node, stack_t, rgb, cost, rays, aov)

    run_parts(work, threads)
    part = slice(run.p0 - y_first * width, run.p1 - y_first * width)
    aov_part = aov.reshape(-1, CHANNELS)[part] if aovs else None
    return rgb.reshape(-1, 3)[part], cost.reshape(-1)[part], rays.reshape(-1)[part], aov_part

"""Spot checks: a few pixels of a render rendered again with many more samples, on a sample
stream of their own, so that they are independent of the render and of any later samples of
it. ``tracer.error_estimate`` uses them where a render's own parts cannot tell a pixel's value
(:func:`tracer.error_estimate.pixels_to_check` chooses the pixels).
"""

import numpy as np

from tracer import scene_format as fmt
from tracer.compile import CompiledScene
from tracer.effects import EffectPlan, effect_plan
from tracer.error_estimate import PARTS, SPOT_CHECK_FACTOR
from tracer.render import render_pixels
from tracer.threads import default_threads, run_parts

SEED_BIT = 1 << 62
"""Flipped in the render's seed to make the checks' seed: pixel keys hash the seed
(``tracer.rng.pixel_key``), so the checks draw samples no render with a seed below 2^62
draws."""


def spot_check_settings(settings: fmt.RenderSettings) -> fmt.RenderSettings:
    """The render's settings on the spot checks' own sample stream."""
    return fmt.override(settings, seed=settings.seed ^ SEED_BIT)


def spot_check_spp(render_spp: int) -> int:
    """Samples per pixel of the spot checks of a render of ``render_spp`` (a multiple of
    ``PARTS``)."""
    return PARTS * max(1, SPOT_CHECK_FACTOR * render_spp // PARTS)


def render_spot_checks(
    scene: CompiledScene,
    pixels: np.ndarray,
    spp: int,
    camera: fmt.Camera | None = None,
    settings: fmt.RenderSettings | None = None,
    frame: int = 0,
    threads: int | None = None,
    plan: EffectPlan | None = None,
) -> np.ndarray:
    """(PARTS, P, 3) float64: for each (y, x) of ``pixels`` (P, 2), ``PARTS`` means of
    ``spp // PARTS`` samples each over disjoint ranges of the checks' stream
    (:func:`spot_check_settings`). Pixels are rendered one per thread at a time."""
    camera = camera or scene.camera
    settings = spot_check_settings(settings or scene.render)
    pixels = np.asarray(pixels, dtype=np.int64).reshape(-1, 2)
    if spp < PARTS or spp % PARTS:
        raise ValueError(f"spot checks need a positive multiple of {PARTS} samples, got {spp}")
    ys, xs = pixels.T
    if ((ys < 0) | (ys >= camera.height) | (xs < 0) | (xs >= camera.width)).any():
        raise ValueError(f"spot-check pixels must lie in the {camera.width}x{camera.height} frame")
    if plan is None:
        plan = effect_plan(scene, settings)
    per_part = spp // PARTS
    part_settings = fmt.override(settings, spp=per_part)
    out = np.zeros((PARTS, len(pixels), 3))
    jobs = [(k, i) for i in range(len(pixels)) for k in range(PARTS)]

    def work(first: int, stride: int) -> None:
        for k, i in jobs[first::stride]:
            p = int(ys[i]) * camera.width + int(xs[i])
            run = render_pixels(
                scene, p, p + 1, camera, part_settings, frame, k * per_part, 1, plan
            )
            out[k, i] = run.rgb[0]

    run_parts(work, min(threads or default_threads(), max(1, len(jobs))))
    return out

"""Spot checks: a few pixels of a render rendered again with many more samples, on sample
streams of their own, so that they are independent of the render and of any later samples of
it. ``tracer.accuracy.error_estimate`` uses them where a render's own parts cannot tell a pixel's
value (:func:`tracer.accuracy.error_estimate.pixels_to_check` ranks the pixels).

A check has ``PARTS`` parts, each on its own stream (the render's seed with bit 62 and the
part's number in bits 58-59 flipped), so that a progressive render tops a pixel's check up
from wave to wave instead of rendering it again: :class:`SpotCheckLedger` keeps the sums,
plans each wave's checks within a share of the render's samples, and hands the estimate the
checks of the pixels it chose.
"""

from dataclasses import dataclass, field

import numpy as np

from tracer.accuracy.error_estimate import (
    PARTS,
    SPOT_CHECK_FACTOR,
    SPOT_CHECK_SHARE,
    SPOT_CHECKS,
    SpotChecks,
    pixels_to_check,
)
from tracer.compiled.scene import CompiledScene
from tracer.integrators.effects import EffectPlan, effect_plan
from tracer.kernel.threads import default_threads, run_parts
from tracer.render import render_pixels
from tracer.scene import format as fmt

SEED_BIT = 1 << 62
"""Flipped in the render's seed for the checks' streams: pixel keys hash the whole seed
(``tracer.maths.rng.pixel_key``), so a render's checks never draw its samples (bit 62 differs), and
for seeds below 2^58 no other render or its checks draw them either."""
PART_SHIFT = 58
"""A check's part number goes into the seed at this bit."""
CANDIDATES = 4 * SPOT_CHECKS
"""Pixels a plan considers, most uncertain first: one whose check does not fit the budget
makes way for the next (a pixel checked before only needs its top-up)."""


def spot_check_settings(settings: fmt.RenderSettings, part: int) -> fmt.RenderSettings:
    """The render's settings on part ``part``'s stream of the spot checks."""
    return fmt.override(
        settings, seed=settings.seed ^ SEED_BIT ^ (part << PART_SHIFT), aovs=False, denoise="off"
    )


def render_spot_checks(
    scene: CompiledScene,
    pixels: np.ndarray,
    part_spp: int | np.ndarray,
    part_start: int | np.ndarray = 0,
    camera: fmt.Camera | None = None,
    settings: fmt.RenderSettings | None = None,
    frame: int = 0,
    threads: int | None = None,
    plan: EffectPlan | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """``(parts, work)``: ``parts`` (PARTS, P, 3) float64 is, for each (y, x) of ``pixels``
    (P, 2), the mean of samples ``[part_start, part_start + part_spp)`` of each part's stream
    (:func:`spot_check_settings`); ``work`` (P,) int64 the kernels' work count of each pixel's
    check, every part. ``part_spp`` and ``part_start`` are numbers, or one per pixel. Pixels
    are rendered one per thread at a time."""
    camera = camera or scene.camera
    settings = settings or scene.render
    pixels = np.asarray(pixels, dtype=np.int64).reshape(-1, 2)
    count = np.broadcast_to(np.asarray(part_spp, dtype=np.int64), len(pixels))
    start = np.broadcast_to(np.asarray(part_start, dtype=np.int64), len(pixels))
    if (count < 1).any() or (start < 0).any():
        raise ValueError("spot checks need at least one sample per part from sample 0 on")
    ys, xs = pixels.T
    if ((ys < 0) | (ys >= camera.height) | (xs < 0) | (xs >= camera.width)).any():
        raise ValueError(f"spot-check pixels must lie in the {camera.width}x{camera.height} frame")
    if plan is None:
        plan = effect_plan(scene, settings)
    streams = [spot_check_settings(settings, k) for k in range(PARTS)]
    out = np.zeros((PARTS, len(pixels), 3))
    work = np.zeros((PARTS, len(pixels)), np.int64)
    jobs = [(k, i) for i in range(len(pixels)) for k in range(PARTS)]

    def render(first: int, stride: int) -> None:
        for k, i in jobs[first::stride]:
            p = int(ys[i]) * camera.width + int(xs[i])
            stream = fmt.override(streams[k], spp=int(count[i]))
            run = render_pixels(scene, p, p + 1, camera, stream, frame, int(start[i]), 1, plan)
            out[k, i] = run.rgb[0]
            work[k, i] = run.cost[0]

    run_parts(render, min(threads or default_threads(), max(1, len(jobs))))
    return out, work.sum(axis=0)


@dataclass(frozen=True)
class SpotCheck:
    """Checks to render: for pixel i of ``pixels`` ((P, 2) y, x), samples ``[part_start[i],
    part_start[i] + part_spp[i])`` of every part's stream."""

    pixels: np.ndarray
    part_start: np.ndarray
    part_spp: np.ndarray

    @property
    def samples(self) -> int:
        """Samples the checks take, every part."""
        return int(PARTS * self.part_spp.sum())


@dataclass
class SpotCheckLedger:
    """A progressive render's spot checks: per pixel ever checked, the sums of its parts.

    Each wave, :meth:`plan` picks the pixels to check (most uncertain first), each to
    ``SPOT_CHECK_FACTOR`` times its pixel's samples, topping up what a pixel already has,
    while the work of all checks so far stays within ``SPOT_CHECK_SHARE`` of the render's
    (and at most ``SPOT_CHECKS`` pixels); a pixel checked before whose top-up does not fit
    keeps its older check. Work is the kernels' work count (deterministic,
    unlike seconds): a check is priced at its pixel's work per sample in its last check, or
    the render's mean before its first (checked pixels, glints and caustics, often cost
    several times the mean); without the render's work, every sample counts one. :meth:`add`
    takes the rendered checks; :meth:`checks` gives the estimate the planned pixels that were
    rendered.
    """

    pixels: int
    """Pixels of the frame."""
    sums: dict[tuple[int, int], np.ndarray] = field(default_factory=dict)
    """Per pixel (y, x): (PARTS, 3) sums of each part's samples."""
    counts: dict[tuple[int, int], int] = field(default_factory=dict)
    """Per pixel: samples per part in ``sums``."""
    rates: dict[tuple[int, int], float] = field(default_factory=dict)
    """Per pixel: work per sample of its last check."""
    spent: float = 0.0
    """Work of every check so far."""
    planned: list[tuple[int, int]] = field(default_factory=list)
    """The pixels of the last plan."""
    rate: float = 1.0
    """The render's mean work per pixel sample at the last plan (1 without its work)."""

    def plan(
        self, parts: np.ndarray, spp: int | np.ndarray, work: float | None = None
    ) -> SpotCheck | None:
        """The checks to render for a render of ``spp`` samples per pixel (one number, or each
        pixel's (H, W) after adaptive sampling: a check takes ``SPOT_CHECK_FACTOR`` times its
        own pixel's) whose parts are ``parts`` ((PARTS, H, W, 3)) and whose work so far is
        ``work`` (None: count samples), or None when none is needed or affordable."""
        spp = np.broadcast_to(np.asarray(spp, np.int64), np.shape(parts)[1:3])
        samples = int(spp.sum())
        self.rate = work / samples if work else 1.0
        budget = SPOT_CHECK_SHARE * samples * self.rate - self.spent
        chosen, starts, needs = [], [], []
        for y, x in pixels_to_check(parts, CANDIDATES):
            key = (int(y), int(x))
            need = max(1, SPOT_CHECK_FACTOR * int(spp[key]) // PARTS)
            have = self.counts.get(key, 0)
            cost = PARTS * max(0, need - have) * self._rate(key)
            if cost <= budget:  # top it up to ``need``
                budget -= cost
                starts.append(have)
            elif have > 0:  # keep the samples it has: fewer, but as independent
                starts.append(need)
            else:
                continue
            chosen.append(key)
            needs.append(need)
            if len(chosen) == SPOT_CHECKS:
                break
        self.planned = chosen
        todo = [i for i, start in enumerate(starts) if start < needs[i]]
        if not todo:
            return None
        return SpotCheck(
            np.array([chosen[i] for i in todo], dtype=np.int64).reshape(-1, 2),
            np.array([starts[i] for i in todo], dtype=np.int64),
            np.array([needs[i] - starts[i] for i in todo], dtype=np.int64),
        )

    def _rate(self, key: tuple[int, int]) -> float:
        """The work per sample a check of pixel ``key`` is priced at."""
        return self.rates.get(key, self.rate)

    def add(
        self,
        request: SpotCheck,
        pixels: np.ndarray,
        parts: np.ndarray,
        work: np.ndarray | None = None,
    ) -> None:
        """Add the checks of ``request`` that were rendered: ``pixels`` ((P', 2), a subset of
        the request's), their (PARTS, P', 3) parts and (P',) work (None: priced as planned).
        The others lack samples, so :meth:`checks` leaves them out. All or nothing: checks that
        are not the request's are refused (ValueError) before anything is added."""
        rows = {(int(y), int(x)): i for i, (y, x) in enumerate(request.pixels)}
        keys = [(int(y), int(x)) for y, x in np.asarray(pixels, dtype=np.int64).reshape(-1, 2)]
        parts = np.asarray(parts, dtype=np.float64)
        if parts.shape != (PARTS, len(keys), 3):
            raise ValueError(f"expected spot-check parts of shape {(PARTS, len(keys), 3)}")
        if work is not None and np.shape(work) != (len(keys),):
            raise ValueError(f"expected the work of {len(keys)} spot checks")
        if len(set(keys)) != len(keys) or any(k not in rows for k in keys):
            raise ValueError("spot checks must be distinct pixels of the request")
        for key in keys:
            if self.counts.get(key, 0) != request.part_start[rows[key]]:
                raise ValueError(f"spot check of pixel {key} does not continue its samples")
        for j, key in enumerate(keys):
            n = int(request.part_spp[rows[key]])
            self.sums[key] = self.sums.get(key, np.zeros((PARTS, 3))) + parts[:, j] * n
            self.counts[key] = self.counts.get(key, 0) + n
            if work is None:
                self.spent += PARTS * n * self._rate(key)
            else:
                self.spent += float(work[j])
                self.rates[key] = float(work[j]) / (PARTS * n)

    def checks(self) -> SpotChecks | None:
        """The checks of the last plan's pixels that have samples (None: none): all the plan
        asked for, or fewer where the budget or a failed tracer left a pixel's older check."""
        keys = [k for k in self.planned if self.counts.get(k, 0) > 0]
        if not keys:
            return None
        parts = np.stack([self.sums[k] / self.counts[k] for k in keys], axis=1)
        return SpotChecks(np.array(keys, dtype=np.int64), parts)

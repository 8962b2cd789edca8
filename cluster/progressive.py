"""Progressive frames: render until an estimated error or a time budget is reached.

A frame is rendered in *waves* (after pbrt's ``ImageTileIntegrator::Render``), each wave made
of ``PARTS`` parts with the same number of samples per pixel over disjoint sample ranges, so
the parts are independent estimates of the same image. Their spread estimates the error of
their mean without a reference (``tracer.accuracy.error_estimate``), or says it cannot be estimated
yet (None). Waves double the samples so far (at most ``MAX_PART_SPP`` per part), and shrink to what
the goal still needs: when a target error is set and estimated, the samples predicted to reach
it (error falls as 1/sqrt(samples)); when a time budget is set, the samples predicted to fit in
what is left of it (from the last wave's seconds per sample). The frame stops after a complete
wave whose estimate meets the target, when the next wave would not fit in the budget, or at
``max_spp``. While the error is not estimable, a target keeps the waves going.

After each wave, the few pixels whose error the parts cannot tell (a light smaller than a
pixel, seen by one part) are *spot-checked* before the estimate: rendered again,
independently, to ``SPOT_CHECK_FACTOR`` times the frame's samples, topping up their checks of
earlier waves (``tracer.accuracy.spot_check``).

With adaptive sampling (``cluster.adaptive``; ``mode`` ``auto``, ``on`` or ``off``), a wave
gives each pixel the first ``counts[i]`` of its parts' samples, by the pixel's estimated share
of the error after the earlier waves: a noisy pixel may take more than the wave's mean, a
quiet one less. Every part of a wave gives a pixel the same count, so each pixel's parts stay
independent and identically distributed, and the estimate stays calibrated. Waves are sized
by the mean samples per pixel; ``spp`` is the sample range the waves used (each wave's as long
as the most a pixel took), :attr:`ProgressiveFrame.pixel_spp` is what each pixel took;
``max_spp`` bounds their mean.

A frame that is to be denoised (:class:`DenoisedTarget`) measures the target on the denoised
image instead, once its parts are deep enough for that estimate
(``tracer.accuracy.denoised_error``): each wave's mean is denoised and its error estimated; until
then, the beauty's estimate decides.

:class:`ProgressiveFrame` is the state and the rules, with no Ray in it (a caller may drive it
one part at a time, as the service does between other work); :func:`progressive_step` renders
its next part through a :class:`cluster.coordinator.Coordinator`, and :func:`render_progressive`
repeats that to the end (as the command line does).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np

from cluster import adaptive
from tracer.accuracy.denoised_error import denoise_and_estimate
from tracer.accuracy.error_estimate import PARTS, estimate_rel_error
from tracer.accuracy.spot_check import SpotCheck, SpotCheckLedger
from tracer.integrators.aov import CHANNELS, IDS, aov_layers
from tracer.post.denoise import DenoiseFailed
from tracer.post.guides import prefilter_argument
from tracer.request import FrameRequest
from tracer.scene import format as fmt

if TYPE_CHECKING:
    from cluster.frame import Frame
    from cluster.scene_graph import SceneGraph

MAX_PART_SPP = 64
"""Most samples per pixel one part of a wave adds."""
DEFAULT_MAX_SPP = 1 << 16
"""Samples per pixel at which a frame stops whatever its error (unless the goal says less)."""
PLAN_MARGIN = 1.1
"""Factor on the samples predicted to reach a target error: a wave sized exactly to the
prediction falls just short about half the time, which costs a whole extra wave."""


@dataclass(frozen=True)
class Goal:
    """When a progressive frame stops: at ``target_error`` (estimated relative RMS error,
    ``tracer.accuracy.error_estimate``; of the denoised frame where :class:`DenoisedTarget` says
    so), after ``time_budget`` seconds, or at ``max_spp`` samples per pixel (on average, with
    adaptive sampling), whichever comes first. At least one wave (``PARTS`` spp) is always
    rendered."""

    target_error: float | None = None
    time_budget: float | None = None
    max_spp: int = DEFAULT_MAX_SPP

    def __post_init__(self) -> None:
        if self.target_error is not None and not (
            math.isfinite(self.target_error) and self.target_error > 0.0
        ):
            raise ValueError(f"target error must be a positive number, got {self.target_error}")
        if self.time_budget is not None and not (
            math.isfinite(self.time_budget) and self.time_budget > 0.0
        ):
            raise ValueError(f"time budget must be a positive number, got {self.time_budget}")
        if self.max_spp < PARTS:
            raise ValueError(f"max_spp must be at least {PARTS} (one wave), got {self.max_spp}")


@dataclass(frozen=True)
class DenoisedTarget:
    """A target error measured on the frame denoised at ``quality`` (the guides ``prefilter``
    names prefiltered, True: both), as the frame's output will be."""

    quality: str
    prefilter: bool | tuple[str, ...]  # ``tracer.post.denoise.denoise``'s

    @classmethod
    def of(cls, settings: fmt.RenderSettings, goal: Goal) -> DenoisedTarget | None:
        """The target of a frame rendered with ``settings`` to ``goal``: None unless it has a
        target error and is denoised with guides (``denoise_prefilter`` ``auto`` left unresolved
        counts as on)."""
        if goal.target_error is None or settings.denoise == "off" or not settings.renders_aovs:
            return None
        return cls(settings.denoise, prefilter_argument(settings.denoise_prefilter))


@dataclass(frozen=True)
class Part:
    """A part of a wave to render: samples ``[sample_start, sample_start + spp)`` of every
    pixel, or with ``counts`` (int32, row-major) ``[sample_start, sample_start + counts[i])``
    of pixel ``i``."""

    sample_start: int
    spp: int
    index: int
    """Which of the wave's ``PARTS`` parts (0 first)."""
    counts: np.ndarray | None = field(default=None, compare=False, repr=False)


@dataclass
class WaveRecord:
    """The state after a complete wave."""

    spp: int
    error: float | None
    seconds: float
    """Seconds since the frame started."""
    checked: int = 0
    """Pixels spot-checked for the estimate."""
    error_of: str = "beauty"
    """Which image ``error`` is of: the ``beauty`` or the ``denoised`` one."""
    mean_spp: float = 0.0
    """Samples per pixel taken so far, on average (``spp`` without adaptive sampling)."""
    adaptive: bool = False
    """Whether this wave's pixels took unequal samples."""


@dataclass
class ProgressiveFrame:
    """One frame's ``PARTS`` accumulators and the rules that size waves and stop them.

    Call :meth:`next_part` and render what it names: a :class:`Part` (hand the image to
    :meth:`add_part`) or, after a wave, a :class:`SpotCheck` (hand the checked pixels and
    their parts to :meth:`add_spot_checks`); repeat until it returns None. ``clock``
    (seconds) is injectable for tests.
    """

    width: int
    height: int
    goal: Goal
    clock: Callable[[], float] = time.monotonic
    denoised: DenoisedTarget | None = None
    """Measure the target on the denoised frame (the parts must carry AOVs)."""
    adaptive: str = "off"
    """Adaptive sampling: ``auto``, ``on`` or ``off`` (``cluster.adaptive``); ``auto`` is off
    for a :class:`DenoisedTarget` (its gain with the denoiser is not measured)."""
    sums: np.ndarray = field(init=False, repr=False)
    """Per part, the sum of its samples' images, float64 (PARTS, H, W, 3)."""
    part_spp: int = 0
    """Samples per pixel in each part after the last complete wave (the sample range; with
    adaptive sampling at least the most a pixel has)."""
    part_counts: np.ndarray = field(init=False, repr=False)
    """Samples of each pixel in each part after the last complete wave, int64 (H, W)."""
    work: float | None = 0.0
    """The kernels' work count of every part so far (None once a part came without it)."""
    error: float | None = None
    """The estimated relative RMS error of :attr:`image` after the last complete wave (None
    before the first, and while it cannot be estimated yet)."""
    stopped: str | None = None
    """Why the frame stopped: ``target_error``, ``time_budget`` or ``max_spp``."""
    waves: list[WaveRecord] = field(default_factory=list)
    started: float | None = None
    _pending: Part | SpotCheck | None = None
    _ledger: SpotCheckLedger = field(init=False, repr=False)
    _wave_parts: list[Part] = field(default_factory=list)
    """The current wave's parts rendered so far."""
    _wave_adaptive: bool = False
    _wave_seconds: float = 0.0
    _last_wave: tuple[float, float] = (0.0, 0.0)
    """Samples per pixel (mean) and seconds of the last complete wave."""
    _rates: np.ndarray | None = None
    """The next wave's sampling rates (``cluster.adaptive``; None: uniform)."""

    def __post_init__(self) -> None:
        if self.adaptive not in adaptive.MODES:
            raise ValueError(f"adaptive must be one of {', '.join(adaptive.MODES)}")
        self.sums = np.zeros((PARTS, self.height, self.width, 3), np.float64)
        self.part_counts = np.zeros((self.height, self.width), np.int64)
        self.aov_sums: np.ndarray | None = None
        """Sample-weighted sums of the parts' AOVs (H, W, ``aov.CHANNELS``), when they carry
        them."""
        self.aov_ids: np.ndarray | None = None
        """The id columns (``aov.IDS``) of the first part, which holds every pixel's sample 0:
        ids are not averaged."""
        self._ledger = SpotCheckLedger(self.width * self.height)

    @property
    def spp(self) -> int:
        """Samples per pixel taken so far (every part)."""
        return PARTS * self.part_spp + sum(p.spp for p in self._wave_parts)

    @property
    def pixel_spp(self) -> np.ndarray:
        """Samples taken so far of each pixel (every part), int64 (H, W)."""
        spp = PARTS * self.part_counts
        for part in self._wave_parts:
            spp = spp + (part.spp if part.counts is None else self._grid(part.counts))
        return spp

    @property
    def mean_spp(self) -> float:
        """Samples per pixel taken so far, on average over the pixels."""
        return adaptive.mean(self.pixel_spp)

    def _grid(self, counts: np.ndarray) -> np.ndarray:
        return counts.reshape(self.height, self.width).astype(np.int64)

    def _weights(self, part: Part) -> int | np.ndarray:
        """What the part's mean image is multiplied by to give its sums: its samples."""
        return part.spp if part.counts is None else self._grid(part.counts)[..., None]

    @property
    def done(self) -> bool:
        return self.stopped is not None

    @property
    def elapsed(self) -> float:
        """Seconds since the first part was handed out."""
        return 0.0 if self.started is None else self.clock() - self.started

    @property
    def image(self) -> np.ndarray:
        """The mean of every sample taken, float32 (H, W, 3)."""
        return (self.sums.sum(axis=0) / np.maximum(1, self.pixel_spp)[..., None]).astype(np.float32)

    @property
    def aov(self) -> np.ndarray | None:
        """The AOVs' mean over every sample taken, float32 (H, W, ``aov.CHANNELS``), with the
        first part's ids; None when the parts carry none."""
        if self.aov_sums is None:
            return None
        mean = (self.aov_sums / np.maximum(1, self.pixel_spp)[..., None]).astype(np.float32)
        mean[..., IDS] = self.aov_ids
        return mean

    def summary(self) -> dict:
        """The goal, the estimate and why the frame stopped (for an image's metadata)."""
        goal = self.goal
        return {
            "target_error": goal.target_error,
            "time_budget": goal.time_budget,
            "max_spp": goal.max_spp,
            "error_estimate": self.error,
            "spp": self.spp,
            "mean_spp": self.mean_spp,
            "adaptive": self.adaptive,
            "adaptive_waves": sum(w.adaptive for w in self.waves),
            "waves": len(self.waves),
            "spot_checks": self.waves[-1].checked if self.waves else 0,
            "error_of": self.waves[-1].error_of if self.waves else None,
            "stopped": self.stopped,
        }

    def next_part(self) -> Part | SpotCheck | None:
        """The part or spot check to render next, or None when the frame is done."""
        if self.stopped is not None:
            return None
        if self._pending is not None:
            return self._pending
        if self.started is None:
            self.started = self.clock()
        if self._wave_parts:
            first = self._wave_parts[0]
            spp, counts = first.spp, first.counts
        else:
            spp, counts = self._next_part_spp(), None
            if self._rates is not None:
                counts = adaptive.wave_counts(self._rates, spp)
                spp = int(counts.max())
        self._pending = Part(self.spp, spp, len(self._wave_parts), counts)
        return self._pending

    def add_part(
        self,
        rgb: np.ndarray,
        seconds: float,
        work: float | None = None,
        aov: np.ndarray | None = None,
    ) -> None:
        """Add the rendered part (float (H, W, 3), the mean of its samples) that
        :meth:`next_part` named; ``seconds`` is what rendering it took, ``work`` the kernels'
        work count (the spot checks' budget; without it they count samples), ``aov`` the
        part's AOVs (H, W, ``aov.CHANNELS``) when it carries them (every part or none)."""
        part = self._pending
        if not isinstance(part, Part):
            raise RuntimeError("add_part without a pending part (call next_part first)")
        if rgb.shape != self.sums.shape[1:]:
            raise ValueError(f"expected an image of shape {self.sums.shape[1:]}, got {rgb.shape}")
        if (aov is None) != (self.aov_sums is None) and self.spp > 0:
            raise ValueError("every part of a frame carries AOVs, or none does")
        if aov is not None and np.shape(aov) != (self.height, self.width, CHANNELS):
            raise ValueError(f"expected AOVs of shape {(self.height, self.width, CHANNELS)}")
        self._pending = None
        if aov is not None:
            if self.aov_sums is None:
                self.aov_sums = np.zeros(np.shape(aov), np.float64)
            self.aov_sums += np.asarray(aov, np.float64) * self._weights(part)
            if part.sample_start == 0:
                self.aov_ids = np.array(aov[..., IDS], np.float32)
        self.work = None if work is None or self.work is None else self.work + float(work)
        self.sums[part.index] += np.asarray(rgb, np.float64) * self._weights(part)
        self._wave_parts.append(part)
        self._wave_seconds = seconds if part.index == 0 else self._wave_seconds + seconds
        if len(self._wave_parts) < PARTS:
            return
        self.part_spp += part.spp
        wave_spp = float(part.spp)
        if part.counts is None:
            self.part_counts += part.spp
        else:
            self.part_counts += self._grid(part.counts)
            wave_spp = adaptive.mean(part.counts)
        self._wave_parts = []
        self._last_wave = (PARTS * wave_spp, self._wave_seconds)
        self._wave_adaptive = part.counts is not None
        self._pending = self._ledger.plan(self._parts(), PARTS * self.part_counts, self.work)
        if self._pending is None:
            self._end_wave()

    def add_spot_checks(
        self,
        pixels: np.ndarray,
        parts: np.ndarray,
        seconds: float,
        work: np.ndarray | None = None,
    ) -> None:
        """Add the spot checks that :meth:`next_part` named: the pixels checked ((P', 2), a
        subset of those named, e.g. none when the checks failed), their (PARTS, P', 3) parts
        and (P',) work; ``seconds`` is what rendering them took."""
        request = self._pending
        if not isinstance(request, SpotCheck):
            raise RuntimeError("add_spot_checks without a pending spot check")
        self._ledger.add(request, pixels, parts, work)  # all or nothing
        self._pending = None
        wave_spp, wave_seconds = self._last_wave
        self._last_wave = (wave_spp, wave_seconds + seconds)
        self._end_wave()

    def _parts(self) -> np.ndarray:
        """The parts' mean images (PARTS, H, W, 3) after the last complete wave."""
        return self.sums / self.part_counts[..., None]

    def _end_wave(self) -> None:
        checks = self._ledger.checks()
        parts = self._parts()
        self.error = estimate_rel_error(parts, checks=checks)
        error_of = "beauty"
        target = self.denoised
        if target is not None and self.aov_sums is not None:
            guides = aov_layers(self.aov)
            try:
                _, denoised_error = denoise_and_estimate(
                    parts,
                    int(self.part_counts.min()),
                    guides["albedo"],
                    guides["normal"],
                    target.quality,
                    target.prefilter,
                    seed=self.spp,
                )
            except (ValueError, DenoiseFailed):  # a frame OIDN cannot take: the beauty decides
                denoised_error = None
            if denoised_error is not None:
                self.error, error_of = denoised_error, "denoised"
        checked = 0 if checks is None else len(checks.pixels)
        self.waves.append(
            WaveRecord(
                self.spp,
                self.error,
                self.elapsed,
                checked,
                error_of,
                self.mean_spp,
                self._wave_adaptive,
            )
        )
        self._check_stop()
        if self.stopped is None:
            mode = self.adaptive
            if mode == "auto" and self.denoised is not None:  # not measured with the denoiser
                mode = "off"
            self._rates = adaptive.next_rates(mode, parts, self.part_counts, self.part_spp)

    def _check_stop(self) -> None:
        goal = self.goal
        if goal.target_error is not None and self.error is not None:
            if self.error <= goal.target_error:
                self.stopped = "target_error"
                return
        if goal.max_spp - self.mean_spp < PARTS:
            self.stopped = "max_spp"
        elif goal.time_budget is not None and self._fits_in_budget() < 1:
            self.stopped = "time_budget"

    def _fits_in_budget(self) -> int:
        """Samples per part the rest of the budget can pay for, at the last wave's rate."""
        wave_spp, wave_seconds = self._last_wave
        remaining = self.goal.time_budget - self.elapsed
        if wave_seconds <= 0.0:
            return MAX_PART_SPP if remaining > 0.0 else 0
        return int(remaining / (PARTS * wave_seconds / wave_spp))

    def _next_part_spp(self) -> int:
        """Samples per part of the next wave, on average over the pixels (at least 1:
        ``_check_stop`` stopped the frame if none fits). Waves double the mean samples so far
        (the sample range, without adaptive sampling)."""
        goal = self.goal
        if self.spp == 0:
            return 1
        taken = self.mean_spp
        share = 1.0 if self._rates is None else adaptive.mean(self._rates)
        room = int((goal.max_spp - taken) / (PARTS * share))
        spp = min(MAX_PART_SPP, int(taken) // PARTS, room)
        if goal.target_error is not None and self.error is not None and self.error > 0.0:
            needed = taken * (self.error / goal.target_error) ** 2 * PLAN_MARGIN
            spp = min(spp, max(1, math.ceil((needed - taken) / (PARTS * share))))
        if goal.time_budget is not None:
            fits = self._fits_in_budget()
            if self._rates is not None:  # rounding up adds less than a sample per pixel
                fits = max(0, fits - 1)
            spp = min(spp, int(fits / share))
        return max(1, spp)


def part_request(request: FrameRequest, part: Part) -> FrameRequest:
    """``request`` (resolved) restricted to ``part``'s samples."""
    return replace(
        request,
        settings=fmt.override(request.settings, spp=part.spp),
        sample_start=part.sample_start,
        counts=part.counts,
    )


def progressive_step(
    coordinator,
    progress: ProgressiveFrame,
    request: FrameRequest,
    graph: SceneGraph | None = None,
) -> Frame | None:
    """Render what ``progress`` names next for ``request`` (a resolved camera and settings;
    the part sets spp and sample_start) through ``coordinator`` (a ``Coordinator``) and add
    it. Returns the coordinator's ``Frame`` of a part, None after spot checks."""
    step = progress.next_part()
    start = time.monotonic()
    if isinstance(step, SpotCheck):
        pixels, parts, work = coordinator.render_spot_checks(step, request, graph)
        progress.add_spot_checks(pixels, parts, time.monotonic() - start, work)
        return None
    part = part_request(request, step)
    done = coordinator.render_frame(part, graph)
    progress.add_part(done.rgb, time.monotonic() - start, float(done.cost.sum()), done.aov)
    return done


def render_progressive(
    coordinator,
    goal: Goal,
    frame: int = 0,
    on_part: Callable[[ProgressiveFrame, Frame | None], None] | None = None,
) -> ProgressiveFrame:
    """Render ``frame`` of the coordinator's scene, with its camera and settings (whose spp
    the waves choose), in waves until ``goal``. ``on_part(progress, frame)`` sees each part
    and each wave's spot checks as they complete (``frame``: the coordinator's ``Frame`` of
    the latest part, its timings and effect plan)."""
    state = coordinator.graph.state
    request = FrameRequest(frame, state.camera, state.render)
    progress = ProgressiveFrame(
        state.camera.width,
        state.camera.height,
        goal,
        denoised=DenoisedTarget.of(state.render, goal),
        adaptive=state.render.adaptive,
    )
    done = None
    while not progress.done:
        part = progressive_step(coordinator, progress, request)
        done = part if part is not None else done
        if on_part is not None:
            on_part(progress, done)
    return progress

"""Progressive frames: render until an estimated error or a time budget is reached.

A frame is rendered in *waves* (after pbrt's ``ImageTileIntegrator::Render``), each wave made
of two halves A and B with the same number of samples per pixel over disjoint sample ranges,
so A and B are independent estimates of the same image. Their difference estimates the error
of their mean without a reference (``tracer.error_estimate``). Waves double the samples so far
(at most ``MAX_WAVE_SPP`` per half), and shrink to what the goal still needs: when a target
error is set, the samples predicted to reach it (error falls as 1/sqrt(samples)); when a time
budget is set, the samples predicted to fit in what is left of it (from the last wave's
seconds per sample). The frame stops after a complete wave that meets the target, when the
next wave would not fit in the budget, or at ``max_spp``.

:class:`ProgressiveFrame` is the state and the rules, with no Ray in it (a caller may drive it
one half at a time, as the service does between other work); :func:`render_progressive`
drives it through a :class:`cluster.coordinator.Coordinator`.
"""

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from tracer import scene_format as fmt
from tracer.error_estimate import estimate_rel_error

MAX_WAVE_SPP = 64
"""Most samples per pixel one half of a wave adds."""
DEFAULT_MAX_SPP = 1 << 16
"""Samples per pixel at which a frame stops whatever its error (unless the goal says less)."""
PLAN_MARGIN = 1.1
"""Factor on the samples predicted to reach a target error: a wave sized exactly to the
prediction falls just short about half the time, which costs a whole extra wave."""


@dataclass(frozen=True)
class Goal:
    """When a progressive frame stops: at ``target_error`` (estimated relative RMS error,
    ``tracer.error_estimate``), after ``time_budget`` seconds, or at ``max_spp`` samples per
    pixel, whichever comes first. At least one wave (2 spp) is always rendered."""

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
        if self.max_spp < 2:
            raise ValueError(
                f"max_spp must be at least 2 (one sample per half), got {self.max_spp}"
            )


@dataclass(frozen=True)
class Half:
    """A half wave to render: samples ``[sample_start, sample_start + spp)`` of every pixel."""

    sample_start: int
    spp: int
    first: bool
    """True for half A (a wave's first), False for half B."""


@dataclass
class WaveRecord:
    """The state after a complete wave."""

    spp: int
    error: float
    seconds: float
    """Seconds since the frame started."""


@dataclass
class ProgressiveFrame:
    """One frame's two accumulators and the rules that size waves and stop them.

    Call :meth:`next_half`, render the half it names, hand the image to :meth:`add_half`;
    repeat until :meth:`next_half` returns None. ``clock`` (seconds) is injectable for tests.
    """

    width: int
    height: int
    goal: Goal
    clock: Callable[[], float] = time.monotonic
    sum_a: np.ndarray = field(init=False, repr=False)
    sum_b: np.ndarray = field(init=False, repr=False)
    spp_a: int = 0
    spp_b: int = 0
    error: float | None = None
    """The estimated relative RMS error of :attr:`image` after the last complete wave."""
    stopped: str | None = None
    """Why the frame stopped: ``target_error``, ``time_budget`` or ``max_spp``."""
    waves: list[WaveRecord] = field(default_factory=list)
    started: float | None = None
    _pending: Half | None = None
    _wave_seconds: float = 0.0
    _last_wave: tuple[int, float] = (0, 0.0)
    """Samples per pixel and seconds of the last complete wave."""

    def __post_init__(self) -> None:
        self.sum_a = np.zeros((self.height, self.width, 3), np.float64)
        self.sum_b = np.zeros((self.height, self.width, 3), np.float64)

    @property
    def spp(self) -> int:
        """Samples per pixel taken so far (both halves)."""
        return self.spp_a + self.spp_b

    @property
    def done(self) -> bool:
        return self.stopped is not None

    @property
    def elapsed(self) -> float:
        """Seconds since the first half was handed out."""
        return 0.0 if self.started is None else self.clock() - self.started

    @property
    def image(self) -> np.ndarray:
        """The mean of every sample taken, float32 (H, W, 3)."""
        return ((self.sum_a + self.sum_b) / max(1, self.spp)).astype(np.float32)

    def next_half(self) -> Half | None:
        """The half to render next, or None when the frame is done."""
        if self.stopped is not None:
            return None
        if self._pending is not None:
            return self._pending
        if self.started is None:
            self.started = self.clock()
        if self.spp_a > self.spp_b:  # B repeats A's sample count over the next range
            half = Half(self.spp, self.spp_a - self.spp_b, first=False)
        else:
            half = Half(self.spp, self._next_wave_half(), first=True)
        self._pending = half
        return half

    def add_half(self, rgb: np.ndarray, seconds: float) -> None:
        """Add the rendered half (float (H, W, 3), the mean of its samples) that
        :meth:`next_half` named; ``seconds`` is what rendering it took."""
        half = self._pending
        if half is None:
            raise RuntimeError("add_half without a pending half (call next_half first)")
        if rgb.shape != self.sum_a.shape:
            raise ValueError(f"expected an image of shape {self.sum_a.shape}, got {rgb.shape}")
        self._pending = None
        weighted = np.asarray(rgb, np.float64) * half.spp
        if half.first:
            self.sum_a += weighted
            self.spp_a += half.spp
            self._wave_seconds = seconds
            return
        self.sum_b += weighted
        self.spp_b += half.spp
        self._wave_seconds += seconds
        self._last_wave = (2 * half.spp, self._wave_seconds)
        self.error = estimate_rel_error(self.sum_a / self.spp_a, self.sum_b / self.spp_b)
        self.waves.append(WaveRecord(self.spp, self.error, self.elapsed))
        self._check_stop()

    def _check_stop(self) -> None:
        goal = self.goal
        if goal.target_error is not None and self.error <= goal.target_error:
            self.stopped = "target_error"
        elif goal.max_spp - self.spp < 2:
            self.stopped = "max_spp"
        elif goal.time_budget is not None and self._fits_in_budget() < 1:
            self.stopped = "time_budget"

    def _fits_in_budget(self) -> int:
        """Samples per half the rest of the budget can pay for, at the last wave's rate."""
        wave_spp, wave_seconds = self._last_wave
        remaining = self.goal.time_budget - self.elapsed
        if wave_seconds <= 0.0:
            return MAX_WAVE_SPP if remaining > 0.0 else 0
        return int(remaining / (2.0 * wave_seconds / wave_spp))

    def _next_wave_half(self) -> int:
        """Samples per half of the next wave (at least 1: ``_check_stop`` stopped the frame
        if none fits)."""
        goal = self.goal
        room = (goal.max_spp - self.spp) // 2
        if self.spp == 0:
            return 1
        half = min(MAX_WAVE_SPP, self.spp_a, room)  # double the samples so far
        if goal.target_error is not None and self.error is not None and self.error > 0.0:
            needed = self.spp * (self.error / goal.target_error) ** 2 * PLAN_MARGIN
            half = min(half, max(1, math.ceil((needed - self.spp) / 2)))
        if goal.time_budget is not None:
            half = min(half, self._fits_in_budget())
        return max(1, half)


def render_progressive(
    coordinator,
    goal: Goal,
    frame: int = 0,
    camera: fmt.Camera | None = None,
    settings: fmt.RenderSettings | None = None,
    on_half: Callable[[ProgressiveFrame, object], None] | None = None,
) -> ProgressiveFrame:
    """Render ``frame`` through ``coordinator`` (a ``Coordinator``) in waves until ``goal``.

    ``camera`` and ``settings`` default to the scene's; ``settings.spp`` is ignored (the waves
    choose it). ``on_half(progress, frame)`` sees each half as it completes (the coordinator's
    ``Frame``: its timings and effect plan).
    """
    state = coordinator.graph.state
    camera = camera or state.camera
    settings = settings or state.render
    progress = ProgressiveFrame(camera.width, camera.height, goal)
    while (half := progress.next_half()) is not None:
        start = time.monotonic()
        done = coordinator.render_frame(
            frame, camera, fmt.override(settings, spp=half.spp), half.sample_start
        )
        progress.add_half(done.rgb, time.monotonic() - start)
        if on_half is not None:
            on_half(progress, done)
    return progress

"""Balancers from tracer speeds alone: ``robin-hood``, ``perfect`` and ``perfect-smooth``
(Bikker 7.3.3), which ignore how the cost of a frame's work units varies."""

import math
from collections.abc import Sequence

import numpy as np

from cluster.balancing.base import (
    Balancer,
    TracerReport,
    check_reports,
    check_split_args,
    even_split,
    fill_unknown,
    proportional_split,
    ranges_from_edges,
    usable,
)
from cluster.balancing.tail_plan import UnitRange


class RobinHood(Balancer):
    """After each frame the tracer that finished last gives one step of units to the tracer
    that finished first; the split is otherwise kept. Starts from an even split.

    The step is ``step`` image lines' worth of units if given, else ``STEP_FRACTION`` of the
    frame's units rounded, at least one unit: one at 96 units, five at 480. The source leaves
    the step open; a fixed single line cannot keep up with a tall frame (it needs hundreds of
    frames to move a quarter of 480 lines), and the sweep in docs/balancing.md finds about 1%
    of the frame best at both heights. A tracer that joins gets the mean unit count of the
    others; then all counts are scaled to the frame's units (largest remainders, ties in
    tracer order)."""

    name = "robin-hood"
    STEP_FRACTION = 0.01

    def __init__(self, step: int | None = None):
        if step is not None and step < 1:
            raise ValueError("step must be at least one line")
        self.step = step
        self._share: dict[str, float] = {}  # fractions of the frame: the same in any layout

    def step_units(self, units: int, spans: int = 1) -> int:
        """Units moved per frame in a frame of ``units`` units (``step`` image lines are
        ``step * spans`` of them)."""
        if self.step is not None:
            return self.step * spans
        return max(1, round(units * self.STEP_FRACTION))

    def split(self, units: int, tracers: Sequence[str], spans: int = 1) -> list[UnitRange]:
        check_split_args(units, tracers, spans)
        if not any(t in self._share for t in tracers):
            return even_split(units, len(tracers))
        sizes = _apportion(units, fill_unknown(self._share, tracers))
        return ranges_from_edges(np.concatenate(([0], np.cumsum(sizes))))

    def observe(self, units: int, reports: Sequence[TracerReport], spans: int = 1) -> None:
        check_reports(units, reports, spans)
        if not reports or units == 0:
            return
        counts = {r.tracer: r.u1 - r.u0 for r in reports}
        timed = [i for i, r in enumerate(reports) if math.isfinite(r.seconds)]
        if not timed:
            return
        last = max(timed, key=lambda i: reports[i].seconds)  # ties: the first in tracer order
        first = min(timed, key=lambda i: reports[i].seconds)
        if reports[last].seconds <= reports[first].seconds:
            return  # everyone finished together
        give = min(self.step_units(units, spans), counts[reports[last].tracer])
        counts[reports[last].tracer] -= give
        counts[reports[first].tracer] += give
        for tracer, count in counts.items():
            self._share[tracer] = count / units


def _apportion(units: int, weights: np.ndarray) -> np.ndarray:
    """Non-negative integer sizes summing to ``units``, proportional to ``weights`` (largest
    remainder method; ties go to the earlier tracer)."""
    w = np.maximum(np.asarray(weights, dtype=np.float64), 0.0)
    if w.sum() <= 0.0:
        w = np.ones_like(w)
    exact = np.round(units * w / w.sum(), 9)  # whole counts stay whole
    sizes = np.floor(exact).astype(np.int64)
    short = units - int(sizes.sum())
    order = np.argsort(-(exact - sizes), kind="stable")
    sizes[order[:short]] += 1
    return sizes


class Perfect(Balancer):
    """Each tracer's share from its speed in the previous frame, in units per second:
    ``s_i = L_i / t_i`` and ``L_i' = N * s_i / sum_j s_j`` (cut at rounded cumulative shares;
    speeds are kept as fractions of the frame per second, the same in any frame size).
    Differences in cost between units are ignored, so a tracer that drew cheap units looks fast
    and is overloaded next frame (Bikker's "hick-ups").

    A tracer without a usable measurement (empty range, zero seconds) keeps its last speed; a
    tracer never measured gets the mean speed of the others."""

    name = "perfect"

    def __init__(self) -> None:
        self._speed: dict[str, float] = {}  # frames per second, last measurement

    def observe(self, units: int, reports: Sequence[TracerReport], spans: int = 1) -> None:
        check_reports(units, reports, spans)
        for r in reports:
            if r.u1 > r.u0 and usable(r.seconds):
                self._speed[r.tracer] = (r.u1 - r.u0) / units / r.seconds

    def target_shares(self, tracers: Sequence[str]) -> np.ndarray:
        """Fractions of the frame (summing to one) ``perfect`` would give ``tracers``."""
        speeds = fill_unknown(self._speed, tracers)
        return speeds / speeds.sum()

    def split(self, units: int, tracers: Sequence[str], spans: int = 1) -> list[UnitRange]:
        check_split_args(units, tracers, spans)
        if not any(t in self._speed for t in tracers):
            return even_split(units, len(tracers))
        return proportional_split(units, self.target_shares(tracers))


class PerfectSmooth(Perfect):
    """``perfect`` with each tracer's share smoothed over frames: after every frame
    ``F_i <- (1 - alpha) F_i + alpha f_i``, where ``f_i`` is the share ``perfect`` would give
    now. Shares are renormalised over the tracers of each split; a new tracer starts at its
    ``perfect`` share.

    ``alpha = 0.4`` (the newest frame weighs 0.4, one k frames older ``0.4 * 0.6**k``): the
    simulator's sweep (``bench/balance_sim.py --sweep``, docs/balancing.md) finds 0.4 best for
    2-8 tracers on both orbits at every timing noise, 0.5 close; smaller values lag, and from
    0.6 on ``perfect``'s overshoot comes back as an oscillation (on a frame of cheap sky and
    dear ground the loop gain of ``perfect`` is about 2, and ``alpha`` times it must stay
    below 1)."""

    name = "perfect-smooth"
    ALPHA = 0.4

    def __init__(self, alpha: float = ALPHA) -> None:
        super().__init__()
        if not 0.0 < alpha <= 1.0:
            raise ValueError("alpha must be in (0, 1]")
        self.alpha = alpha
        self._share: dict[str, float] = {}

    def observe(self, units: int, reports: Sequence[TracerReport], spans: int = 1) -> None:
        super().observe(units, reports, spans)
        tracers = [r.tracer for r in reports]
        if not tracers or not any(t in self._speed for t in tracers):
            return
        target = self.target_shares(tracers)
        old = self._normalised(tracers, target)
        # Shares of the tracers seen keep their total, so a tracer that sat this frame out
        # keeps its share relative to them.
        known = [self._share[t] for t in tracers if t in self._share]
        total = float(np.mean(known)) * len(tracers) if known else 1.0
        for t, f, g in zip(tracers, target, old, strict=True):
            self._share[t] = total * ((1.0 - self.alpha) * g + self.alpha * f)

    def _normalised(self, tracers: Sequence[str], fallback: np.ndarray) -> np.ndarray:
        """Current shares of ``tracers`` summing to one. An id without a share takes the mean
        share of the others; ``fallback`` when none of them has one."""
        if not any(t in self._share for t in tracers):
            return fallback
        shares = fill_unknown(self._share, tracers)
        return shares / shares.sum()

    def split(self, units: int, tracers: Sequence[str], spans: int = 1) -> list[UnitRange]:
        check_split_args(units, tracers, spans)
        if not any(t in self._share for t in tracers):
            return super().split(units, tracers, spans)
        return proportional_split(units, self._normalised(tracers, self.target_shares(tracers)))

"""Workload balancers (Brigade, Bikker 7.3.3): how a frame's lines are split among tracers.

A balancer gives each tracer one contiguous line range, in tracer order, together covering
``[0, height)`` exactly. Before each frame the coordinator calls ``split``; after it, ``observe``
with what each tracer reported (its range, seconds spent, and the per-line cost of its lines),
so the next split can use them. Splits never change pixels (the tracer is deterministic per
pixel); they change only how long tracers wait for each other.

Balancers (``make_balancer(name)``; formulas and measurements in ``docs/balancing.md``):

- ``none``: even split, no memory (Bikker's reference).
- ``robin-hood``: the tracer that finished last gives one unit of lines to the one that
  finished first.
- ``perfect``: each tracer's share of lines from its lines per second in the previous frame.
- ``perfect-smooth``: ``perfect`` with an exponential moving average of the shares.
- ``cost-aware``: predicts every line's cost from the previous frames' per-line costs and each
  tracer's speed in cost units per second, and cuts the frame so the predicted times are equal
  (the min-max contiguous partition of the predicted costs).
- ``cost-aware-tail`` (``cluster.tail``): ``cost-aware``'s split sent as a head of about 90% of
  each range, the rest handed out in shrinking chunks to whichever tracer finishes first.
  ``cost-aware`` (the default) keeps such a tail only in the file pool of tracers sharing the
  coordinator's machine, where they claim chunks themselves; the split alone is
  ``cost-aware-static``.

State is kept per tracer id, so tracers may join and leave between frames: an id a balancer has
not seen gets a default (an even or mean share). Balancers are deterministic: the same calls
give the same splits.
"""

import bisect
import itertools
import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from cluster.tail import LineRange, TailPlan, cut_head


@dataclass(frozen=True)
class TracerReport:
    """One tracer's share of a finished frame."""

    tracer: str
    y0: int
    y1: int
    seconds: float
    line_cost: np.ndarray
    """int64 (y1 - y0,): the tracer's work per line (node visits plus triangle tests)."""


class Balancer:
    """Base class: even split, no memory (Bikker's ``none``)."""

    name = "none"

    def split(self, height: int, tracers: Sequence[str], spans: int = 1) -> list[LineRange]:
        """Contiguous ranges, one per tracer in order, covering [0, height). A tracer may get
        an empty range when there are more tracers than lines. ``spans``: the frame's lines
        are spans of its image lines, this many per image line (``worker.work_units``)."""
        _check_split_args(height, tracers, spans)
        return even_split(height, len(tracers))

    def observe(self, height: int, reports: Sequence[TracerReport], spans: int = 1) -> None:
        """Learn from a finished frame (reports in tracer order)."""
        _check_reports(height, reports, spans)


def even_split(height: int, parts: int) -> list[LineRange]:
    """``parts`` contiguous ranges whose sizes differ by at most one line."""
    if parts < 1:
        raise ValueError("a split needs at least one tracer")
    edges = [height * k // parts for k in range(parts + 1)]
    return list(itertools.pairwise(edges))


def idle_percent(seconds: Sequence[float]) -> float:
    """Percentage of the frame's tracer time spent waiting for the slowest tracer (Bikker,
    Table 16): ``100 * sum_i (t_max - t_i) / (T * t_max)``; 0 for no tracers or no time."""
    t = np.asarray(seconds, dtype=np.float64)
    if t.size == 0:
        return 0.0
    if not np.all(np.isfinite(t)) or np.any(t < 0.0):
        raise ValueError("seconds must be finite and non-negative")
    t_max = float(t.max())
    if t_max <= 0.0:
        return 0.0
    return float(100.0 * np.sum(t_max - t) / (t.size * t_max))


# --- shared helpers ----------------------------------------------------------------------------


def _check_split_args(height: int, tracers: Sequence[str], spans: int = 1) -> None:
    if height < 0:
        raise ValueError(f"height must be non-negative, not {height}")
    _check_spans(height, spans)
    if len(tracers) < 1:
        raise ValueError("a split needs at least one tracer")
    if len(set(tracers)) != len(tracers):
        raise ValueError("tracer ids must be distinct")


def _check_spans(height: int, spans: int) -> None:
    if spans < 1 or height % spans:
        raise ValueError(f"{height} lines are not whole image lines of {spans} spans each")


def _check_reports(height: int, reports: Sequence[TracerReport], spans: int = 1) -> None:
    """Reject reports that cannot describe a frame of ``height`` lines."""
    _check_spans(height, spans)
    for r in reports:
        if not 0 <= r.y0 <= r.y1 <= height:
            raise ValueError(f"tracer {r.tracer!r}: range [{r.y0}, {r.y1}) not in [0, {height})")
        if np.shape(r.line_cost) != (r.y1 - r.y0,):
            raise ValueError(
                f"tracer {r.tracer!r}: {np.shape(r.line_cost)} line costs for {r.y1 - r.y0} lines"
            )


def _usable(seconds: float) -> bool:
    """A measured time a speed can be derived from."""
    return math.isfinite(seconds) and seconds > 0.0


def ranges_from_edges(edges: Sequence[int]) -> list[LineRange]:
    """``[(e0, e1), (e1, e2), ...]`` from nondecreasing cut positions ``e0 = 0 ... eT = H``."""
    edges = [int(e) for e in edges]
    return list(itertools.pairwise(edges))


def proportional_split(height: int, weights: Sequence[float]) -> list[LineRange]:
    """Contiguous ranges with sizes proportional to ``weights`` (non-negative, not all zero),
    cut at the rounded cumulative fractions ``round(H * sum_{j<k} w_j / sum_j w_j)``."""
    w = np.asarray(weights, dtype=np.float64)
    total = float(w.sum())
    if total <= 0.0 or not math.isfinite(total):
        return even_split(height, len(w))
    fractions = np.concatenate(([0.0], np.cumsum(w) / total))
    edges = np.rint(height * fractions).astype(np.int64)
    edges[0], edges[-1] = 0, height
    return ranges_from_edges(np.maximum.accumulate(np.minimum(edges, height)))


def _fill_unknown(values: dict[str, float], tracers: Sequence[str]) -> np.ndarray:
    """``values`` for ``tracers``; an id without a value gets the mean of the known ones (all 1
    when none is known)."""
    known = [values[t] for t in tracers if t in values]
    default = float(np.mean(known)) if known else 1.0
    return np.array([values.get(t, default) for t in tracers], dtype=np.float64)


def min_max_cuts(
    cost: Sequence[float], speeds: Sequence[float], prefer: Sequence[float] | None = None
) -> list[int]:
    """Cut positions ``0 = e0 <= ... <= eT = H`` of the contiguous, in-order partition of lines
    with costs ``cost`` among tracers with ``speeds`` that minimises the largest predicted time
    ``sum(cost[e_i:e_{i+1}]) / speeds[i]``.

    Among the partitions reaching that minimum, each cut is taken as close as it can be to
    ``prefer`` (fractional positions; default the proportional cut, where the cumulative cost
    reaches the tracers' cumulative share of the speed), so the slack is spread instead of
    being left to the last tracers. ``cost`` must be positive, ``speeds`` positive.
    """
    c = np.asarray(cost, dtype=np.float64)
    v = np.asarray(speeds, dtype=np.float64)
    height, parts = c.size, v.size
    if parts < 1:
        raise ValueError("a split needs at least one tracer")
    if height == 0:
        return [0] * (parts + 1)
    if not (np.all(c > 0.0) and np.all(v > 0.0) and np.all(np.isfinite(c))):
        raise ValueError("min_max_cuts needs positive, finite costs and speeds")
    prefix = np.concatenate(([0.0], np.cumsum(c)))
    total = prefix[-1]
    if prefer is None:
        shares = np.concatenate(([0.0], np.cumsum(v) / v.sum()))
        prefer = np.interp(total * shares, prefix, np.arange(height + 1))
    prefer = np.asarray(prefer, dtype=np.float64)
    sums, rates = prefix.tolist(), v.tolist()  # plain floats: bisect is fast on lists

    def forward(tau: float, edges: list[int] | None = None) -> bool:
        # Each tracer in turn takes as many lines as fit in ``tau``: the latest possible cuts.
        a = 0
        for i in range(parts):
            a = max(a, bisect.bisect_right(sums, sums[a] + tau * rates[i]) - 1)
            if edges is not None:
                edges.append(a)
            elif a >= height:
                return True
        return a >= height

    # Bisect the bottleneck time between the fluid optimum and one fastest tracer doing it all.
    lo, hi = total / v.sum(), total / v.max() * (1.0 + 1e-12)
    if forward(lo):
        hi = lo
    while hi - lo > 1e-9 * hi:
        mid = 0.5 * (lo + hi)
        if forward(mid):
            hi = mid
        else:
            lo = mid
    tau = hi

    # Earliest possible cuts at ``tau`` (the last tracers take as much as they can).
    earliest = [height] * (parts + 1)
    for i in range(parts - 1, -1, -1):
        earliest[i] = bisect.bisect_left(sums, sums[earliest[i + 1]] - tau * rates[i])
    greedy: list[int] = []
    forward(tau, greedy)
    if earliest[0] > 0:  # rounding disagreement at the boundary: keep the greedy cuts
        return [0, *greedy[:-1], height]

    # Walk the cuts, each as near its preferred position as the bottleneck allows.
    edges = [0]
    for k in range(1, parts):
        a = edges[-1]
        latest = bisect.bisect_right(sums, sums[a] + tau * rates[k - 1]) - 1
        low = max(a, earliest[k])
        edges.append(min(max(int(np.rint(prefer[k])), low), max(low, latest)))
    edges.append(height)
    last = prefix[height] - prefix[edges[-2]]
    if last > tau * v[-1] * (1.0 + 1e-9):  # cannot happen in exact arithmetic; stay safe
        return [0, *greedy[:-1], height]
    return edges


# --- robin hood --------------------------------------------------------------------------------


class RobinHood(Balancer):
    """After each frame the tracer that finished last gives one work unit of lines to the
    tracer that finished first; the split is otherwise kept. Starts from an even split.

    The unit is ``unit`` lines if given, else ``UNIT_FRACTION`` of the frame height rounded,
    at least one line: one line at 96 lines, five at 480. The source leaves the unit open; a
    fixed single line cannot keep up with a tall frame (it needs hundreds of frames to move a
    quarter of 480 lines), and the sweep in docs/balancing.md finds about 1% of the height best
    at both heights. A tracer that joins gets the mean line count of the others; then all
    counts are scaled to the frame height (largest remainders, ties in tracer order)."""

    name = "robin-hood"
    UNIT_FRACTION = 0.01

    def __init__(self, unit: int | None = None):
        if unit is not None and unit < 1:
            raise ValueError("unit must be at least one line")
        self.unit = unit
        self._share: dict[str, float] = {}  # fractions of the frame: the same in any layout

    def unit_lines(self, height: int, spans: int = 1) -> int:
        """Lines moved per frame in a frame of ``height`` lines (``unit`` image lines are
        ``unit * spans`` of them)."""
        if self.unit is not None:
            return self.unit * spans
        return max(1, round(height * self.UNIT_FRACTION))

    def split(self, height: int, tracers: Sequence[str], spans: int = 1) -> list[LineRange]:
        _check_split_args(height, tracers, spans)
        if not any(t in self._share for t in tracers):
            return even_split(height, len(tracers))
        sizes = _apportion(height, _fill_unknown(self._share, tracers))
        return ranges_from_edges(np.concatenate(([0], np.cumsum(sizes))))

    def observe(self, height: int, reports: Sequence[TracerReport], spans: int = 1) -> None:
        _check_reports(height, reports, spans)
        if not reports or height == 0:
            return
        lines = {r.tracer: r.y1 - r.y0 for r in reports}
        timed = [i for i, r in enumerate(reports) if math.isfinite(r.seconds)]
        if not timed:
            return
        last = max(timed, key=lambda i: reports[i].seconds)  # ties: the first in tracer order
        first = min(timed, key=lambda i: reports[i].seconds)
        if reports[last].seconds <= reports[first].seconds:
            return  # everyone finished together
        give = min(self.unit_lines(height, spans), lines[reports[last].tracer])
        lines[reports[last].tracer] -= give
        lines[reports[first].tracer] += give
        for tracer, count in lines.items():
            self._share[tracer] = count / height


def _apportion(height: int, weights: np.ndarray) -> np.ndarray:
    """Non-negative integer sizes summing to ``height``, proportional to ``weights`` (largest
    remainder method; ties go to the earlier tracer)."""
    w = np.maximum(np.asarray(weights, dtype=np.float64), 0.0)
    if w.sum() <= 0.0:
        w = np.ones_like(w)
    exact = np.round(height * w / w.sum(), 9)  # whole counts stay whole
    sizes = np.floor(exact).astype(np.int64)
    short = height - int(sizes.sum())
    order = np.argsort(-(exact - sizes), kind="stable")
    sizes[order[:short]] += 1
    return sizes


# --- perfect -----------------------------------------------------------------------------------


class Perfect(Balancer):
    """Each tracer's share from its speed in the previous frame, in lines per second:
    ``s_i = L_i / t_i`` and ``L_i' = H * s_i / sum_j s_j`` (cut at rounded cumulative shares;
    speeds are kept as fractions of the frame per second, the same in any frame size).
    Differences in cost between lines are ignored, so a tracer that drew cheap lines looks fast
    and is overloaded next frame (Bikker's "hick-ups").

    A tracer without a usable measurement (empty range, zero seconds) keeps its last speed; a
    tracer never measured gets the mean speed of the others."""

    name = "perfect"

    def __init__(self) -> None:
        self._speed: dict[str, float] = {}  # frames per second, last measurement

    def observe(self, height: int, reports: Sequence[TracerReport], spans: int = 1) -> None:
        _check_reports(height, reports, spans)
        for r in reports:
            if r.y1 > r.y0 and _usable(r.seconds):
                self._speed[r.tracer] = (r.y1 - r.y0) / height / r.seconds

    def target_shares(self, tracers: Sequence[str]) -> np.ndarray:
        """Fractions of the frame (summing to one) ``perfect`` would give ``tracers``."""
        speeds = _fill_unknown(self._speed, tracers)
        return speeds / speeds.sum()

    def split(self, height: int, tracers: Sequence[str], spans: int = 1) -> list[LineRange]:
        _check_split_args(height, tracers, spans)
        if not any(t in self._speed for t in tracers):
            return even_split(height, len(tracers))
        return proportional_split(height, self.target_shares(tracers))


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

    def observe(self, height: int, reports: Sequence[TracerReport], spans: int = 1) -> None:
        super().observe(height, reports, spans)
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
        shares = _fill_unknown(self._share, tracers)
        return shares / shares.sum()

    def split(self, height: int, tracers: Sequence[str], spans: int = 1) -> list[LineRange]:
        _check_split_args(height, tracers, spans)
        if not any(t in self._share for t in tracers):
            return super().split(height, tracers, spans)
        return proportional_split(height, self._normalised(tracers, self.target_shares(tracers)))


# --- cost-aware --------------------------------------------------------------------------------


class CostAware(Balancer):
    """Cut the frame so each tracer's *predicted* time is equal, from a predicted per-line cost
    profile and each tracer's speed in cost units per second.

    - **Profile.** The reports' ``line_cost`` arrays, concatenated, are last frame's cost of
      every line, ``c``. A small bank of forecasters (``PREDICTORS``) each predicts the next
      frame's ``c`` per line by Holt's linear exponential smoothing with a damped trend: a
      level ``L <- a c + (1 - a)(L + phi D)``, a trend ``D <- b (L_new - L) + (1 - b) phi D``,
      and the forecast ``max(L + phi D, 0)``. With ``b = 0`` that is a moving average
      (``a = 1``: last frame), which suits a slow camera, where averaging removes 1-spp noise;
      with a trend it extrapolates features sliding through the frame, which suits a fast one
      (``a = b = 1, phi = 1/2``: last frame plus half of its change). After every frame each
      forecaster is scored by how far its forecast's normalised prefix sum (the cumulative cost
      fraction, which is what places the cuts) was from the frame's, in the max norm, averaged
      over frames with weight ``ERROR_ALPHA``; the split uses the forecaster with the lowest
      score (ties: the first). The forecast is then blurred over ``2 * BLUR + 1`` lines (a
      box filter: a cut on a sharp edge of the profile is the likeliest to be wrong), and every
      line costs at least ``FLOOR`` times the mean (rays are generated and pixels written even
      for the sky); that also makes the prefix sum strictly increasing, so cuts in zero-cost
      stretches are well defined. A profile of another height is resampled through its prefix
      sum.
    - **Speeds.** Tracer i's speed is its measured cost over its seconds, over recent frames:
      ``v_i = W_i / S_i`` with ``W_i <- (1 - gamma) W_i + gamma C_i`` and
      ``S_i <- (1 - gamma) S_i + gamma t_i`` (``gamma = SPEED_ALPHA``, but ``1/n`` for a
      tracer's n-th frame while that is larger: plain means at first, so the first frame, often
      an unrepresentative even split, is forgotten as fast as the data allow). Unlike
      ``perfect``'s lines per second it does not change when a tracer draws cheap or dear
      lines, so it can be smoothed hard against timing noise; and as a ratio of sums it weighs
      each frame by the work done, so a frame in which a tracer drew only sky, and its time was
      mostly fixed overhead, hardly moves it. A range of zero cost says nothing about
      speed and is skipped. A tracer never measured is assumed to run at the mean speed of the
      others in the split.
    - **Cut.** With prefix sums of the predicted cost, the partition minimising the largest
      predicted time ``sum(P[y0:y1]) / v_i`` is found exactly (``min_max_cuts``: bisection on
      the bottleneck time with a greedy feasibility test); among optimal partitions each cut is
      moved as close as allowed to the proportional cut (where the cumulative predicted cost
      reaches the tracers' cumulative share of the total speed), which is the rounded
      fractional cut whenever rounding does not lengthen the slowest tracer.

    Before any profile is known, every line is assumed to cost the same.
    """

    name = "cost-aware-static"
    PREDICTORS: tuple[tuple[float, float, float], ...] = (
        (1.0, 0.0, 1.0),  # last frame
        (0.6, 0.0, 1.0),  # moving averages
        (0.3, 0.0, 1.0),
        (1.0, 1.0, 0.5),  # last frame plus half its change
        (1.0, 0.5, 1.0),  # last frame plus a smoothed trend
        (0.6, 0.3, 1.0),  # smoothed level and trend
    )
    """``(a, b, phi)`` of each forecaster: level and trend weights and trend damping."""
    ERROR_ALPHA = 0.1
    """Weight of the newest frame in each forecaster's score: about ten frames of memory, so
    the choice follows a change of camera motion within a second without flickering."""
    BLUR = 1
    """Half-width in lines of the box filter over the predicted profile."""
    SPEED_ALPHA = 0.2
    """Weight of the newest frame in each tracer's averaged cost and seconds: about five
    frames of memory. The sweep finds 0.1-0.2 best at 5% timing noise and 0.2-0.3 at 1%; a
    real tracer's speed also drifts (other load, clocks), which argues against going lower."""
    FLOOR = 1e-3
    """Least cost of a line, as a fraction of the mean line cost."""

    def __init__(
        self,
        predictors: Sequence[tuple[float, float, float]] = PREDICTORS,
        blur: int = BLUR,
        speed_alpha: float = SPEED_ALPHA,
        error_alpha: float = ERROR_ALPHA,
    ) -> None:
        if not predictors:
            raise ValueError("at least one predictor is needed")
        for a, b, phi in predictors:
            if not (0.0 < a <= 1.0 and 0.0 <= b <= 1.0 and 0.0 <= phi <= 1.0):
                raise ValueError("predictors need 0 < a <= 1, 0 <= b <= 1 and 0 <= phi <= 1")
        if not 0.0 < speed_alpha <= 1.0 or not 0.0 < error_alpha <= 1.0:
            raise ValueError("speed_alpha and error_alpha must be in (0, 1]")
        if blur < 0:
            raise ValueError("blur must be non-negative")
        self.blur = blur
        self.speed_alpha = speed_alpha
        self.error_alpha = error_alpha
        self._predictors = [_Forecaster(a, b, phi) for a, b, phi in predictors]
        self._work: dict[str, tuple[float, float, int]] = {}  # (cost, seconds) averages, frames

    # The profile -------------------------------------------------------------------------------

    def observe(self, height: int, reports: Sequence[TracerReport], spans: int = 1) -> None:
        _check_reports(height, reports, spans)
        for r in reports:
            self._observe_speed(r.tracer, float(np.sum(r.line_cost)), r.seconds)
        self._observe_profile(height, reports, spans)

    def _observe_speed(self, tracer: str, spent: float, seconds: float) -> None:
        """One smoothing step of ``tracer``'s cost and seconds (skipped without cost or a
        usable time)."""
        if not (spent > 0.0 and _usable(seconds)):
            return
        work, time, count = self._work.get(tracer, (0.0, 0.0, 0))
        g = max(self.speed_alpha, 1.0 / (count + 1))  # plain means until 1/gamma frames
        self._work[tracer] = ((1 - g) * work + g * spent, (1 - g) * time + g * seconds, count + 1)

    def _observe_profile(
        self, height: int, reports: Sequence[TracerReport], spans: int = 1
    ) -> None:
        """Score the forecasters against the frame's line costs, then update them."""
        if height == 0 or not reports:
            return
        cost = np.zeros(height)
        seen = np.zeros(height, dtype=bool)
        for r in reports:
            cost[r.y0 : r.y1] = np.asarray(r.line_cost, dtype=np.float64)
            seen[r.y0 : r.y1] = True
        if not seen.any():
            return
        known = self._predictors[0].level is not None
        if not seen.all():  # lines nobody reported: keep the forecast, else the mean
            predicted = self.predicted_profile(height, spans)[~seen] if known else None
            cost[~seen] = cost[seen].mean() if predicted is None else predicted
        if known and cost.sum() > 0.0:
            actual = _cumulative_fraction(cost)
            for p in self._predictors:
                shape = _cumulative_fraction(self._shape(p, height, spans))
                miss = float(np.max(np.abs(shape - actual)))
                p.error = miss if p.error is None else p.error + self.error_alpha * (miss - p.error)
        for p in self._predictors:
            p.update(cost, spans)

    def _shape(self, forecaster: "_Forecaster", height: int, spans: int = 1) -> np.ndarray:
        """``forecaster``'s prediction for ``height`` lines (``spans`` per image line),
        blurred and floored."""
        p = _box_blur(forecaster.forecast(height, spans), self.blur, spans)
        mean = float(p.mean())
        if not mean > 0.0:
            return np.ones(height)
        return np.maximum(p, self.FLOOR * mean)

    @property
    def chosen(self) -> int:
        """Index into ``PREDICTORS`` of the forecaster the next split uses (lowest score; ties
        and unscored forecasters: the first)."""
        scores = [math.inf if p.error is None else p.error for p in self._predictors]
        return int(np.argmin(scores))

    def predicted_profile(self, height: int, spans: int = 1) -> np.ndarray:
        """Predicted cost of each of ``height`` lines (``spans`` per image line) next frame
        (float64, all positive)."""
        if self._predictors[0].level is None or height == 0:
            return np.ones(height)
        return self._shape(self._predictors[self.chosen], height, spans)

    # Speeds and the cut ------------------------------------------------------------------------

    def speeds(self, tracers: Sequence[str]) -> np.ndarray:
        """Smoothed speeds (cost units per second) of ``tracers``; unknown ids get the mean."""
        known = {t: work / time for t, (work, time, _) in self._work.items()}
        return _fill_unknown(known, tracers)

    def split(self, height: int, tracers: Sequence[str], spans: int = 1) -> list[LineRange]:
        _check_split_args(height, tracers, spans)
        if height == 0:
            return [(0, 0)] * len(tracers)
        edges = min_max_cuts(self.predicted_profile(height, spans), self.speeds(tracers))
        return ranges_from_edges(edges)


class _Forecaster:
    """Holt's linear exponential smoothing of a per-line cost profile with a damped trend
    (Gardner): level weight ``a``, trend weight ``b`` (``b = 0``: a moving average), damping
    ``phi``; ``error`` is its running score. Its profile has ``spans`` lines per image line."""

    def __init__(self, a: float, b: float, phi: float) -> None:
        self.a, self.b, self.phi = a, b, phi
        self.level: np.ndarray | None = None
        self.trend: np.ndarray | None = None
        self.spans = 1
        self.error: float | None = None

    def forecast(self, height: int, spans: int = 1) -> np.ndarray:
        """``max(level + phi trend, 0)``, resampled to ``height`` lines of ``spans`` per image
        line."""
        assert self.level is not None and self.trend is not None
        profile = self.level + self.phi * self.trend
        return np.maximum(_resample(profile, height, self.spans, spans), 0.0)

    def update(self, cost: np.ndarray, spans: int = 1) -> None:
        if self.level is None or self.trend is None:
            self.level, self.trend, self.spans = cost.copy(), np.zeros_like(cost), spans
            return
        level = _resample(self.level, cost.size, self.spans, spans)
        trend = _resample(self.trend, cost.size, self.spans, spans)
        new = self.a * cost + (1.0 - self.a) * (level + self.phi * trend)
        self.trend = self.b * (new - level) + (1.0 - self.b) * self.phi * trend
        self.level, self.spans = new, spans


def _box_blur(values: np.ndarray, radius: int, spans: int = 1) -> np.ndarray:
    """Every line's mean over ``2 radius + 1`` image lines (clipped to the frame): with
    ``spans`` lines per image line, over the same span of the image lines around it."""
    lines = values.size // spans
    if radius <= 0 or lines < 2:
        return values
    grid = values.reshape(lines, spans)
    prefix = np.concatenate((np.zeros((1, spans)), np.cumsum(grid, axis=0)))
    y = np.arange(lines)
    lo, hi = np.maximum(y - radius, 0), np.minimum(y + radius + 1, lines)
    return ((prefix[hi] - prefix[lo]) / (hi - lo)[:, None]).reshape(-1)


def _cumulative_fraction(cost: np.ndarray) -> np.ndarray:
    """Normalised prefix sum ``[0, c0, c0 + c1, ...] / sum(c)`` (length H + 1)."""
    prefix = np.concatenate(([0.0], np.cumsum(cost)))
    return prefix / prefix[-1]


def _resample(profile: np.ndarray, height: int, spans_from: int = 1, spans: int = 1) -> np.ndarray:
    """``profile`` (cost per line, ``spans_from`` lines per image line) resampled to ``height``
    lines of ``spans`` per image line, total cost kept: the spans of every image line, then
    the image lines of every span, stretched through their prefix sums."""
    if profile.size == height and spans_from == spans:
        return profile
    grid = _stretch(profile.reshape(-1, spans_from), spans, axis=1)
    return _stretch(grid, height // spans, axis=0).reshape(-1)


def _stretch(values: np.ndarray, size: int, axis: int) -> np.ndarray:
    """``values`` stretched to ``size`` entries along ``axis``, each row's total kept: its
    prefix sum interpolated linearly at the new boundaries."""
    count = values.shape[axis]
    if count == size:
        return values
    rows = np.moveaxis(values, axis, -1)
    prefix = np.concatenate((np.zeros((*rows.shape[:-1], 1)), np.cumsum(rows, axis=-1)), axis=-1)
    at = np.linspace(0.0, count, size + 1)
    left = np.minimum(at.astype(np.int64), count - 1)
    frac = at - left
    sums = prefix[..., left] * (1.0 - frac) + prefix[..., left + 1] * frac
    return np.moveaxis(np.diff(sums, axis=-1), -1, axis)


# --- cost-aware with a dynamic tail -------------------------------------------------------------


class CostAwareTail(CostAware):
    """``cost-aware`` with a dynamic tail (module docstring). ``split`` is the plain cost-aware
    partition (for callers that need one range per tracer); ``plan`` gives heads and a tail.

    The tail's share follows how well heads were predicted: ``z`` times the root mean square
    of the heads' relative time errors (``seconds / predicted - 1``, smoothed over frames with
    weight ``ERROR_ALPHA``), between ``MIN_TAIL`` and ``MAX_TAIL``, where ``z`` is ``Z`` or,
    with many tracers, ``sqrt(2 ln T)`` (about the largest of T normal draws: the tail must
    absorb the overrun of the slowest of T heads, not of a typical one); ``FIRST_TAIL`` while
    nothing is known (the first frame is an even split of unknown costs). No tail when that
    error, in seconds, is worth fewer than ``CALLS_WORTH`` calls, nor with fewer than
    ``MIN_LINES`` lines per tracer. ``fraction`` fixes the heads' share instead (the lines rule
    still applies; ``min_lines=1`` lifts it).

    A ``pooled`` plan (the tail goes to a shared pool the tracers claim chunks from
    themselves: :mod:`worker.line_pool`, :mod:`worker.remote_pool`) always keeps a tail of at
    least ``POOL_MIN_TAIL`` and at most ``POOL_MAX_TAIL`` (a claim costs microseconds to a
    millisecond, not a render call, so no error is too small to be worth it) as long as there
    are ``POOL_MIN_LINES`` lines per tracer, and cuts chunks down to ``POOL_MIN_SECONDS`` of
    predicted work (or twice a claim, and one line), sized for the slowest tracer
    (``TailPlan.take_all``). ``call_tail=False`` gives plans without a pool no tail at all,
    and ``remote_pool=False`` keeps the tail out of the actor pool of several machines
    (``cost-aware``: there its plans are not pooled).

    ``observe`` takes any number of reports per tracer (heads and chunks): the profile from
    all of them, each tracer's speed from the sums of its cost and seconds over the frame (one
    smoothing step per frame). A report whose seconds are not usable (NaN: lines rendered by a
    copy or a reassignment) feeds only the profile."""

    name = "cost-aware-tail"
    Z = 1.5
    MIN_TAIL = 0.02
    MAX_TAIL = 0.15
    FIRST_TAIL = 0.5
    DIVISOR = 2.0
    """Guided self-scheduling's k: a chunk is the remaining tail x speed share / k."""
    MIN_CHUNK = 0.02
    """Least chunk, as a fraction of a tracer's predicted frame time."""
    MIN_SECONDS = 0.01
    """Least chunk in predicted seconds: every call costs a tracer about a millisecond outside
    rendering on the development machine (bench/cluster.py, docs/balancing.md), so a chunk
    should be worth several calls."""
    CALL_SECONDS = 0.002
    """What one more render call costs a tracer: about 0.8 ms between queued calls and 0.4 ms
    of fixed work inside the call (bench/cluster.py), and on a machine where the coordinator
    shares the tracers' cores, its own work for the call (about 1.5 ms of busy time per extra
    call measured with two tracers on the two-core development machine)."""
    CALLS_WORTH = 4.0
    """No tail unless the heads' typical error (rms, in seconds) exceeds this many calls: a
    static split idles about half that error, a tail costs at least one more call per tracer
    and its last chunks' mismatch (simulator: ``bench/balance_sim.py --calls``)."""
    MIN_LINES = 16
    """No tail with fewer image lines per tracer: where a tracer's share is a few lines, a
    chunk queued on a slow tracer at the end costs more than the tail saves (simulator:
    8-128 tracers on 96 lines, 128 on 480)."""
    HEADS_KEPT = 4
    """Frames of head predictions kept (pipelined frames are planned before the ones before
    them are observed)."""
    POOL_MIN_SECONDS = 0.0002
    """Least pooled chunk in predicted seconds: the last chunk is what the other tracer may
    wait for (0.2 ms against 0.5 and 1 ms: 1.06, 1.17 and 1.44% idle, 640x480, two tracers)."""
    POOL_MIN_TAIL = 0.10
    """Least pooled tail: a tracer's speed varies 4-9% from frame to frame on a shared machine
    and a pooled tail costs little more than its chunks (10% against 5%: median idle 0.76
    against 1.02%)."""
    POOL_MAX_TAIL = 0.30
    """Most pooled tail: with 128 tracers at 5% timing noise the heads' rms error is about
    6%, and ``sqrt(2 ln 128) = 3.1`` times that is 18% (simulator, ``bench/balance_sim.py
    --calls --pool``: a 30% cap against 15% gives 1.48 against 3.82% idle on the fast orbit,
    1.22-1.34 against 2.00-2.18 on two other seeds)."""
    POOL_MIN_LINES = 2
    """No pooled tail with fewer lines per tracer (nothing queues behind a pooled chunk)."""

    def __init__(
        self,
        fraction: float | None = None,
        divisor: float = DIVISOR,
        min_chunk: float = MIN_CHUNK,
        min_seconds: float = MIN_SECONDS,
        z: float = Z,
        call_seconds: float = CALL_SECONDS,
        calls_worth: float = CALLS_WORTH,
        min_lines: int = MIN_LINES,
        call_tail: bool = True,
        remote_pool: bool = True,
        **cost_aware,
    ) -> None:
        super().__init__(**cost_aware)
        self.call_tail = call_tail
        self.remote_pool = remote_pool
        """Whether the coordinator may put the tail in the actor pool (:mod:`worker.remote_pool`:
        tracers on several machines, or file pools not possible); the file pool of tracers
        sharing the coordinator's machine is used whenever pools are allowed."""
        if fraction is not None and not 0.0 < fraction <= 1.0:
            raise ValueError("fraction must be in (0, 1]")
        if not divisor > 0.0 or not 0.0 <= min_chunk < 1.0 or not min(z, min_seconds) >= 0.0:
            raise ValueError("divisor must be positive, min_chunk in [0, 1), z, min_seconds >= 0")
        self.fraction = fraction
        self.divisor = divisor
        self.min_chunk = min_chunk
        self.min_seconds = min_seconds
        self.z = z
        self.call_seconds = call_seconds
        self.calls_worth = calls_worth
        self.min_lines = min_lines
        # Predicted seconds of heads not observed yet, oldest first per (tracer, height, spans,
        # y0, y1): with the pipeline, frame N+1 may get the same head as frame N before N is
        # observed.
        self._heads: dict[tuple[str, int, int, int, int], deque[float]] = {}
        self._error2: float | None = None  # smoothed squared relative error of heads

    def head_fraction(
        self, frame_seconds: float = math.inf, pooled: bool = False, tracers: int = 2
    ) -> float:
        """Share of each tracer's predicted cost sent as its head, for a frame of ``tracers``
        predicted to take ``frame_seconds``: everything when the heads' error is too small to
        pay for the calls a tail costs (never for a ``pooled`` tail)."""
        if self.fraction is not None:
            return self.fraction
        least = self.POOL_MIN_TAIL if pooled else self.MIN_TAIL
        if self._error2 is None:
            known = self._predictors[0].level is not None and self._work
            return 1.0 - (least if known else self.FIRST_TAIL)
        spread = math.sqrt(self._error2)
        worth = self.calls_worth * self.call_seconds
        if not pooled and math.isfinite(frame_seconds) and spread * frame_seconds < worth:
            return 1.0
        z = max(self.z, math.sqrt(2.0 * math.log(max(2, tracers))))
        most = self.POOL_MAX_TAIL if pooled else self.MAX_TAIL
        return 1.0 - min(max(z * spread, least), most)

    def plan(
        self,
        height: int,
        tracers: Sequence[str],
        pooled: bool = False,
        spans: int = 1,
        claim_seconds: float = 0.0,
    ) -> TailPlan:
        """Heads (one per tracer, in order) and the tail of the next frame. ``pooled``: the
        tail goes to a shared pool (:mod:`worker.line_pool`, :mod:`worker.remote_pool`), where
        a chunk costs a fraction of a Ray call: smaller chunks, and a tail on smaller frames;
        ``claim_seconds``, what one claim costs a tracer, keeps chunks at least twice that."""
        ranges = self.split(height, tracers, spans)
        profile = self.predicted_profile(height, spans)
        prefix = np.concatenate(([0.0], np.cumsum(profile)))
        speeds = self.speeds(tracers)
        timed = all(t in self._work for t in tracers)
        frame_seconds = prefix[-1] / speeds.sum() if timed else math.inf
        fraction = self.head_fraction(frame_seconds, pooled, len(tracers))
        min_lines = min(self.min_lines, self.POOL_MIN_LINES) if pooled else self.min_lines
        if height < min_lines * spans * len(tracers) or not (pooled or self.call_tail):
            fraction = 1.0
        known = self._predictors[0].level is not None
        heads: list[LineRange] = []
        tail: list[tuple[float, int, int]] = []
        for tracer, speed, (a, b) in zip(tracers, speeds, ranges, strict=True):
            head, rest = cut_head(prefix, a, b, fraction)
            heads.append(head)
            if head[1] > head[0] and known and tracer in self._work:  # a real prediction
                predicted = (prefix[head[1]] - prefix[head[0]]) / speed
                key = (tracer, height, spans, *head)
                queued = self._heads.pop(key, deque())  # re-inserted: the newest is kept
                queued.append(predicted)
                self._heads[key] = queued
            if rest[1] > rest[0]:
                per_line = (prefix[rest[1]] - prefix[rest[0]]) / (rest[1] - rest[0])
                tail.append((-per_line, rest[0], rest[1]))
        while len(self._heads) > self.HEADS_KEPT * len(tracers):
            self._heads.pop(next(iter(self._heads)))
        segments = deque([y0, y1] for _, y0, y1 in sorted(tail))  # dearest first
        return TailPlan(
            tracers=list(tracers),
            heads=heads,
            prefix=prefix,
            speeds={t: float(v) for t, v in zip(tracers, speeds, strict=True)},
            divisor=self.divisor,
            min_chunk=0.0 if pooled else self.min_chunk,
            min_seconds=max(min(self.min_seconds, self.POOL_MIN_SECONDS), 2.0 * claim_seconds)
            if pooled
            else self.min_seconds,
            timed=timed,
            segments=segments,
        )

    def observe(self, height: int, reports: Sequence[TracerReport], spans: int = 1) -> None:
        _check_reports(height, reports, spans)
        work: dict[str, list[float]] = {}
        for r in reports:
            sums = work.setdefault(r.tracer, [0.0, 0.0])
            if r.y1 > r.y0 and _usable(r.seconds):
                sums[0] += float(np.sum(r.line_cost))
                sums[1] += r.seconds
                key = (r.tracer, height, spans, r.y0, r.y1)
                queued = self._heads.get(key)
                predicted = queued.popleft() if queued else None
                if queued is not None and not queued:
                    del self._heads[key]
                if predicted is not None and predicted > 0.0:
                    miss = min(1.0, (r.seconds / predicted - 1.0) ** 2)  # one outlier
                    self._error2 = (
                        miss
                        if self._error2 is None
                        else self._error2 + self.error_alpha * (miss - self._error2)
                    )
        for tracer, (spent, seconds) in work.items():
            self._observe_speed(tracer, spent, seconds)
        self._observe_profile(height, reports, spans)


class CostAwarePooled(CostAwareTail):
    """``cost-aware``, the default: the cost-aware split, with a dynamic tail only where a
    chunk is cheapest, in the file pool of tracers that all share the coordinator's machine
    (:mod:`worker.line_pool`). Across machines the static split alone: ``cost-aware-tail``
    puts the tail in the actor pool there (:mod:`worker.remote_pool`), which the simulator
    finds worth it (1.3 / 2.7 / 4.1% idle with 8 / 32 / 128 tracers against 5.1 / 8.1 /
    11.9%) but which made frames 4-11% slower with two tracers on two Ray nodes of the
    two-core development machine, where the pool actor waits for a core
    (``docs/balancing.md``)."""

    name = "cost-aware"

    def __init__(self, **options) -> None:
        super().__init__(call_tail=False, remote_pool=False, **options)


BALANCERS: dict[str, type[Balancer]] = {
    cls.name: cls
    for cls in (
        Balancer,
        RobinHood,
        Perfect,
        PerfectSmooth,
        CostAware,
        CostAwarePooled,
        CostAwareTail,
    )
}
DEFAULT_BALANCER = CostAwarePooled.name
"""The balancer of the coordinator, ``render`` and ``serve`` unless one is named."""


def make_balancer(name: str) -> Balancer:
    """A fresh balancer by name; ValueError naming the choices for an unknown one."""
    try:
        return BALANCERS[name]()
    except KeyError:
        raise ValueError(
            f"unknown balancer {name!r}; choose one of {', '.join(sorted(BALANCERS))}"
        ) from None

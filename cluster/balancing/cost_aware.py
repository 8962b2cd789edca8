"""``cost-aware-static``: cut a frame's work units so every tracer's predicted time is equal,
from a forecast of each unit's cost and each tracer's speed in cost per second
(``docs/balancing.md``)."""

import bisect
import math
from collections.abc import Sequence

import numpy as np

from cluster.balancing.base import (
    Balancer,
    TracerReport,
    check_reports,
    check_split_args,
    fill_unknown,
    ranges_from_edges,
    usable,
)
from cluster.balancing.tail_plan import UnitRange


def min_max_cuts(
    cost: Sequence[float], speeds: Sequence[float], prefer: Sequence[float] | None = None
) -> list[int]:
    """Cut positions ``0 = e0 <= ... <= eT = N`` of the contiguous, in-order partition of units
    with costs ``cost`` among tracers with ``speeds`` that minimises the largest predicted time
    ``sum(cost[e_i:e_{i+1}]) / speeds[i]``.

    Among the partitions reaching that minimum, each cut is taken as close as it can be to
    ``prefer`` (fractional positions; default the proportional cut, where the cumulative cost
    reaches the tracers' cumulative share of the speed), so the slack is spread instead of
    being left to the last tracers. ``cost`` must be positive, ``speeds`` positive.
    """
    c = np.asarray(cost, dtype=np.float64)
    v = np.asarray(speeds, dtype=np.float64)
    units, parts = c.size, v.size
    if parts < 1:
        raise ValueError("a split needs at least one tracer")
    if units == 0:
        return [0] * (parts + 1)
    if not (np.all(c > 0.0) and np.all(v > 0.0) and np.all(np.isfinite(c))):
        raise ValueError("min_max_cuts needs positive, finite costs and speeds")
    prefix = np.concatenate(([0.0], np.cumsum(c)))
    total = prefix[-1]
    if prefer is None:
        shares = np.concatenate(([0.0], np.cumsum(v) / v.sum()))
        prefer = np.interp(total * shares, prefix, np.arange(units + 1))
    prefer = np.asarray(prefer, dtype=np.float64)
    sums, rates = prefix.tolist(), v.tolist()  # plain floats: bisect is fast on lists

    def forward(tau: float, edges: list[int] | None = None) -> bool:
        # Each tracer in turn takes as many units as fit in ``tau``: the latest possible cuts.
        a = 0
        for i in range(parts):
            a = max(a, bisect.bisect_right(sums, sums[a] + tau * rates[i]) - 1)
            if edges is not None:
                edges.append(a)
            elif a >= units:
                return True
        return a >= units

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
    earliest = [units] * (parts + 1)
    for i in range(parts - 1, -1, -1):
        earliest[i] = bisect.bisect_left(sums, sums[earliest[i + 1]] - tau * rates[i])
    greedy: list[int] = []
    forward(tau, greedy)
    if earliest[0] > 0:  # rounding disagreement at the boundary: keep the greedy cuts
        return [0, *greedy[:-1], units]

    # Walk the cuts, each as near its preferred position as the bottleneck allows.
    edges = [0]
    for k in range(1, parts):
        a = edges[-1]
        latest = bisect.bisect_right(sums, sums[a] + tau * rates[k - 1]) - 1
        low = max(a, earliest[k])
        edges.append(min(max(int(np.rint(prefer[k])), low), max(low, latest)))
    edges.append(units)
    last = prefix[units] - prefix[edges[-2]]
    if last > tau * v[-1] * (1.0 + 1e-9):  # cannot happen in exact arithmetic; stay safe
        return [0, *greedy[:-1], units]
    return edges


class CostAware(Balancer):
    """Cut the frame so each tracer's *predicted* time is equal, from a predicted per-unit cost
    profile and each tracer's speed in cost units per second.

    - **Profile.** The reports' ``unit_cost`` arrays, concatenated, are last frame's cost of
      every unit, ``c``. A small bank of forecasters (``PREDICTORS``) each predicts the next
      frame's ``c`` per unit by Holt's linear exponential smoothing with a damped trend: a
      level ``L <- a c + (1 - a)(L + phi D)``, a trend ``D <- b (L_new - L) + (1 - b) phi D``,
      and the forecast ``max(L + phi D, 0)``. With ``b = 0`` that is a moving average
      (``a = 1``: last frame), which suits a slow camera, where averaging removes 1-spp noise;
      with a trend it extrapolates features sliding through the frame, which suits a fast one
      (``a = b = 1, phi = 1/2``: last frame plus half of its change). After every frame each
      forecaster is scored by how far its forecast's normalised prefix sum (the cumulative cost
      fraction, which is what places the cuts) was from the frame's, in the max norm, averaged
      over frames with weight ``ERROR_ALPHA``; the split uses the forecaster with the lowest
      score (ties: the first). The forecast is then blurred over ``2 * BLUR + 1`` image lines (a
      box filter: a cut on a sharp edge of the profile is the likeliest to be wrong), and every
      unit costs at least ``FLOOR`` times the mean (rays are generated and pixels written even
      for the sky); that also makes the prefix sum strictly increasing, so cuts in zero-cost
      stretches are well defined. A profile of another layout is resampled through its prefix
      sum.
    - **Speeds.** Tracer i's speed is its measured cost over its seconds, over recent frames:
      ``v_i = W_i / S_i`` with ``W_i <- (1 - gamma) W_i + gamma C_i`` and
      ``S_i <- (1 - gamma) S_i + gamma t_i`` (``gamma = SPEED_ALPHA``, but ``1/n`` for a
      tracer's n-th frame while that is larger: plain means at first, so the first frame, often
      an unrepresentative even split, is forgotten as fast as the data allow). Unlike
      ``perfect``'s units per second it does not change when a tracer draws cheap or dear
      units, so it can be smoothed hard against timing noise; and as a ratio of sums it weighs
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

    Before any profile is known, every unit is assumed to cost the same.
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
    """Half-width in image lines of the box filter over the predicted profile."""
    SPEED_ALPHA = 0.2
    """Weight of the newest frame in each tracer's averaged cost and seconds: about five
    frames of memory. The sweep finds 0.1-0.2 best at 5% timing noise and 0.2-0.3 at 1%; a
    real tracer's speed also drifts (other load, clocks), which argues against going lower."""
    FLOOR = 1e-3
    """Least cost of a unit, as a fraction of the mean unit cost."""

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

    def observe(self, units: int, reports: Sequence[TracerReport], spans: int = 1) -> None:
        check_reports(units, reports, spans)
        for r in reports:
            self._observe_speed(r.tracer, float(np.sum(r.unit_cost)), r.seconds)
        self._observe_profile(units, reports, spans)

    def _observe_speed(self, tracer: str, spent: float, seconds: float) -> None:
        """One smoothing step of ``tracer``'s cost and seconds (skipped without cost or a
        usable time)."""
        if not (spent > 0.0 and usable(seconds)):
            return
        work, time, count = self._work.get(tracer, (0.0, 0.0, 0))
        g = max(self.speed_alpha, 1.0 / (count + 1))  # plain means until 1/gamma frames
        self._work[tracer] = ((1 - g) * work + g * spent, (1 - g) * time + g * seconds, count + 1)

    def _observe_profile(self, units: int, reports: Sequence[TracerReport], spans: int = 1) -> None:
        """Score the forecasters against the frame's unit costs, then update them."""
        if units == 0 or not reports:
            return
        cost = np.zeros(units)
        seen = np.zeros(units, dtype=bool)
        for r in reports:
            cost[r.u0 : r.u1] = np.asarray(r.unit_cost, dtype=np.float64)
            seen[r.u0 : r.u1] = True
        if not seen.any():
            return
        known = self._predictors[0].level is not None
        if not seen.all():  # units nobody reported: keep the forecast, else the mean
            predicted = self.predicted_profile(units, spans)[~seen] if known else None
            cost[~seen] = cost[seen].mean() if predicted is None else predicted
        if known and cost.sum() > 0.0:
            actual = _cumulative_fraction(cost)
            for p in self._predictors:
                shape = _cumulative_fraction(self._shape(p, units, spans))
                miss = float(np.max(np.abs(shape - actual)))
                p.error = miss if p.error is None else p.error + self.error_alpha * (miss - p.error)
        for p in self._predictors:
            p.update(cost, spans)

    def _shape(self, forecaster: "_Forecaster", units: int, spans: int = 1) -> np.ndarray:
        """``forecaster``'s prediction for ``units`` units (``spans`` per image line),
        blurred and floored."""
        p = _box_blur(forecaster.forecast(units, spans), self.blur, spans)
        mean = float(p.mean())
        if not mean > 0.0:
            return np.ones(units)
        return np.maximum(p, self.FLOOR * mean)

    @property
    def chosen(self) -> int:
        """Index into ``PREDICTORS`` of the forecaster the next split uses (lowest score; ties
        and unscored forecasters: the first)."""
        scores = [math.inf if p.error is None else p.error for p in self._predictors]
        return int(np.argmin(scores))

    def predicted_profile(self, units: int, spans: int = 1) -> np.ndarray:
        """Predicted cost of each of ``units`` units (``spans`` per image line) next frame
        (float64, all positive)."""
        if self._predictors[0].level is None or units == 0:
            return np.ones(units)
        return self._shape(self._predictors[self.chosen], units, spans)

    # Speeds and the cut ------------------------------------------------------------------------

    def speeds(self, tracers: Sequence[str]) -> np.ndarray:
        """Smoothed speeds (cost units per second) of ``tracers``; unknown ids get the mean."""
        known = {t: work / time for t, (work, time, _) in self._work.items()}
        return fill_unknown(known, tracers)

    def split(self, units: int, tracers: Sequence[str], spans: int = 1) -> list[UnitRange]:
        check_split_args(units, tracers, spans)
        if units == 0:
            return [(0, 0)] * len(tracers)
        edges = min_max_cuts(self.predicted_profile(units, spans), self.speeds(tracers))
        return ranges_from_edges(edges)


class _Forecaster:
    """Holt's linear exponential smoothing of a per-unit cost profile with a damped trend
    (Gardner): level weight ``a``, trend weight ``b`` (``b = 0``: a moving average), damping
    ``phi``; ``error`` is its running score. Its profile has ``spans`` units per image line."""

    def __init__(self, a: float, b: float, phi: float) -> None:
        self.a, self.b, self.phi = a, b, phi
        self.level: np.ndarray | None = None
        self.trend: np.ndarray | None = None
        self.spans = 1
        self.error: float | None = None

    def forecast(self, units: int, spans: int = 1) -> np.ndarray:
        """``max(level + phi trend, 0)``, resampled to ``units`` units of ``spans`` per image
        line."""
        assert self.level is not None and self.trend is not None
        profile = self.level + self.phi * self.trend
        return np.maximum(_resample(profile, units, self.spans, spans), 0.0)

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
    """Every unit's mean over ``2 radius + 1`` image lines (clipped to the frame): with
    ``spans`` units per image line, over the same span of the image lines around it."""
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


def _resample(profile: np.ndarray, units: int, spans_from: int = 1, spans: int = 1) -> np.ndarray:
    """``profile`` (cost per unit, ``spans_from`` units per image line) resampled to ``units``
    units of ``spans`` per image line, total cost kept: the spans of every image line, then
    the image lines of every span, stretched through their prefix sums."""
    if profile.size == units and spans_from == spans:
        return profile
    grid = _stretch(profile.reshape(-1, spans_from), spans, axis=1)
    return _stretch(grid, units // spans, axis=0).reshape(-1)


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

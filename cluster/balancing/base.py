"""The balancer interface, the reports balancers learn from, and the helpers they share.

A balancer gives each tracer one contiguous range of a frame's work units
(:mod:`worker.work_units`), in tracer order, together covering ``[0, units)`` exactly.
"""

import itertools
import math
from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from cluster.balancing.tail_plan import TailPlan, UnitRange


@dataclass(frozen=True)
class TracerReport:
    """One tracer's range of a finished frame."""

    tracer: str
    u0: int
    u1: int
    seconds: float
    unit_cost: np.ndarray
    """int64 (u1 - u0,): the tracer's work per unit (node visits plus triangle tests)."""


class Balancer(ABC):
    """What the coordinator asks of a balancer: ``split`` a frame's units among tracers (or
    ``plan`` heads and a dynamic tail), and ``observe`` what the tracers then did."""

    name: ClassVar[str]
    remote_pool: bool = False
    """Whether a dynamic tail may go to the actor pool of tracers on several machines
    (:mod:`worker.remote_pool`); the file pool of tracers sharing the coordinator's machine is
    used whenever a plan has a tail and pools are allowed."""

    @abstractmethod
    def split(self, units: int, tracers: Sequence[str], spans: int = 1) -> list[UnitRange]:
        """Contiguous ranges, one per tracer in order, covering [0, units). A tracer may get
        an empty range when there are more tracers than units. ``spans``: units per image
        line (``worker.work_units``)."""

    @abstractmethod
    def observe(self, units: int, reports: Sequence[TracerReport], spans: int = 1) -> None:
        """Learn from a finished frame (reports in tracer order)."""

    def plan(
        self,
        units: int,
        tracers: Sequence[str],
        pooled: bool = False,
        spans: int = 1,
        claim_seconds: float = 0.0,
    ) -> TailPlan | None:
        """Heads and a dynamic tail of the next frame (``cluster.balancing.tail``), or None:
        the frame is the ``split`` alone."""
        return None


class EvenSplit(Balancer):
    """Even split, no memory (Bikker's ``none``)."""

    name = "none"

    def split(self, units: int, tracers: Sequence[str], spans: int = 1) -> list[UnitRange]:
        check_split_args(units, tracers, spans)
        return even_split(units, len(tracers))

    def observe(self, units: int, reports: Sequence[TracerReport], spans: int = 1) -> None:
        check_reports(units, reports, spans)


def even_split(units: int, parts: int) -> list[UnitRange]:
    """``parts`` contiguous ranges whose sizes differ by at most one unit."""
    if parts < 1:
        raise ValueError("a split needs at least one tracer")
    edges = [units * k // parts for k in range(parts + 1)]
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


def check_split_args(units: int, tracers: Sequence[str], spans: int = 1) -> None:
    """Refuse a split of a negative count, of units that are not whole lines, or among no or
    repeated tracers."""
    if units < 0:
        raise ValueError(f"units must be non-negative, not {units}")
    _check_spans(units, spans)
    if len(tracers) < 1:
        raise ValueError("a split needs at least one tracer")
    if len(set(tracers)) != len(tracers):
        raise ValueError("tracer ids must be distinct")


def _check_spans(units: int, spans: int) -> None:
    if spans < 1 or units % spans:
        raise ValueError(f"{units} units are not whole image lines of {spans} spans each")


def check_reports(units: int, reports: Sequence[TracerReport], spans: int = 1) -> None:
    """Reject reports that cannot describe a frame of ``units`` units."""
    _check_spans(units, spans)
    for r in reports:
        if not 0 <= r.u0 <= r.u1 <= units:
            raise ValueError(f"tracer {r.tracer!r}: range [{r.u0}, {r.u1}) not in [0, {units})")
        if np.shape(r.unit_cost) != (r.u1 - r.u0,):
            raise ValueError(
                f"tracer {r.tracer!r}: {np.shape(r.unit_cost)} unit costs for {r.u1 - r.u0} units"
            )


def usable(seconds: float) -> bool:
    """A measured time a speed can be derived from."""
    return math.isfinite(seconds) and seconds > 0.0


def ranges_from_edges(edges: Sequence[int]) -> list[UnitRange]:
    """``[(e0, e1), (e1, e2), ...]`` from nondecreasing cut positions ``e0 = 0 ... eT = N``."""
    edges = [int(e) for e in edges]
    return list(itertools.pairwise(edges))


def proportional_split(units: int, weights: Sequence[float]) -> list[UnitRange]:
    """Contiguous ranges with sizes proportional to ``weights`` (non-negative, not all zero),
    cut at the rounded cumulative fractions ``round(N * sum_{j<k} w_j / sum_j w_j)``."""
    w = np.asarray(weights, dtype=np.float64)
    total = float(w.sum())
    if total <= 0.0 or not math.isfinite(total):
        return even_split(units, len(w))
    fractions = np.concatenate(([0.0], np.cumsum(w) / total))
    edges = np.rint(units * fractions).astype(np.int64)
    edges[0], edges[-1] = 0, units
    return ranges_from_edges(np.maximum.accumulate(np.minimum(edges, units)))


def fill_unknown(values: dict[str, float], tracers: Sequence[str]) -> np.ndarray:
    """``values`` for ``tracers``; an id without a value gets the mean of the known ones (all 1
    when none is known)."""
    known = [values[t] for t in tracers if t in values]
    default = float(np.mean(known)) if known else 1.0
    return np.array([values.get(t, default) for t in tracers], dtype=np.float64)

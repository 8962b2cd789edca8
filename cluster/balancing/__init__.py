"""Workload balancers (Brigade, Bikker 7.3.3): how a frame's work units are split among tracers.

A balancer (``base.Balancer``) gives each tracer one contiguous range of the frame's work
units (:mod:`worker.work_units`), in tracer order, together covering ``[0, units)`` exactly.
Before each frame the coordinator asks for a ``plan`` (heads and a dynamic tail, from the
balancers that keep one) or else a ``split``; after it, it calls ``observe`` with what each
tracer reported (its range, seconds spent, and the per-unit cost of its units), so the next
split can use them. ``remote_pool`` says whether a tail may go to the actor pool of several
machines. Splits never change pixels (the tracer is deterministic per pixel); they change only
how long tracers wait for each other.

Balancers (``make_balancer(name)``; formulas and measurements in ``docs/balancing.md``):

- ``none``: even split, no memory (Bikker's reference).
- ``robin-hood``: the tracer that finished last gives a step of units to the one that
  finished first.
- ``perfect``: each tracer's share of units from its units per second in the previous frame.
- ``perfect-smooth``: ``perfect`` with an exponential moving average of the shares.
- ``cost-aware``: predicts every unit's cost from the previous frames' per-unit costs and each
  tracer's speed in cost units per second, and cuts the frame so the predicted times are equal
  (the min-max contiguous partition of the predicted costs).
- ``cost-aware-tail`` (``tail``, ``tail_plan``): ``cost-aware``'s split sent as a head of
  about 90% of each range, the rest handed out in shrinking chunks to whichever tracer
  finishes first.
  ``cost-aware`` (the default) keeps such a tail only in the file pool of tracers sharing the
  coordinator's machine, where they claim chunks themselves; the split alone is
  ``cost-aware-static``.

State is kept per tracer id, so tracers may join and leave between frames: an id a balancer has
not seen gets a default (an even or mean share). Balancers are deterministic: the same calls
give the same splits.
"""

from cluster.balancing.base import (
    Balancer,
    EvenSplit,
    TracerReport,
    even_split,
    idle_percent,
)
from cluster.balancing.cost_aware import CostAware, min_max_cuts
from cluster.balancing.speed_shares import Perfect, PerfectSmooth, RobinHood
from cluster.balancing.tail import CostAwarePooled, CostAwareTail
from cluster.balancing.tail_plan import TailPlan, UnitRange

__all__ = [
    "BALANCERS",
    "DEFAULT_BALANCER",
    "Balancer",
    "CostAware",
    "CostAwarePooled",
    "CostAwareTail",
    "EvenSplit",
    "Perfect",
    "PerfectSmooth",
    "RobinHood",
    "TailPlan",
    "TracerReport",
    "UnitRange",
    "even_split",
    "idle_percent",
    "make_balancer",
    "min_max_cuts",
]

BALANCERS: dict[str, type[Balancer]] = {
    cls.name: cls
    for cls in (
        EvenSplit,
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

"""The dynamic tail: a cost-aware split whose last units are handed out while the frame renders.

``cost-aware`` fixes every tracer's range before the frame starts, so any error in the
predicted costs or speeds (a tracer's speed varies a few percent from frame to frame on a
shared machine) becomes idle time. ``cost-aware-tail`` keeps its static split for most of the
work and adapts the rest within the frame:

1. **Heads.** The cost-aware partition ``[a_i, b_i)`` is cut in two: a contiguous *head* worth
   ``fraction`` of the tracer's predicted cost, sent at once, and the rest of the range, which
   goes to the tail. The rest is taken from whichever end of the range gives it more units (the
   cheaper end: finer chunks for the same cost).
2. **Tail.** The tail's segments are handed out in chunks of whole, contiguous units, dearest
   segments first, so the last chunks are the cheapest (guided self-scheduling): a tracer that
   asks gets ``remaining predicted cost x its share of the speed / divisor`` (``R / (k T)`` for
   equal tracers), at least ``min_chunk`` of its predicted frame time, at least
   ``min_seconds`` of predicted work (every call costs the tracer about a millisecond outside
   rendering) and at least one unit.
3. **Queue ahead.** The coordinator sends every tracer its head and one chunk at once, and a
   new chunk whenever one of its calls returns, so a tracer always has a call queued (Ray runs
   an actor's calls in order) and never waits for the round trip.

How big the tail is (and whether there is one) is the balancer's business,
``cluster.balancing.tail.CostAwareTail``; this module holds the plan it makes for one frame
(``TailPlan``) and how a range is cut into head and rest (``cut_head``). Pixels never depend
on how units were handed out. Formulas and measurements: ``docs/balancing.md``.
"""

from collections import deque
from dataclasses import dataclass, field

import numpy as np

UnitRange = tuple[int, int]


@dataclass
class TailPlan:
    """One frame's heads and its tail: ``next_chunk(tracer)`` hands out the tail."""

    tracers: list[str]
    heads: list[UnitRange]
    """Each tracer's static range, in tracer order (may be empty)."""
    prefix: np.ndarray
    """Prefix sums of the predicted cost per unit (length N + 1)."""
    speeds: dict[str, float]
    """Predicted speed (cost per second) of each tracer of the split."""
    divisor: float = 2.0
    min_chunk: float = 0.0
    """Least chunk, as a fraction of the tracer's predicted frame time."""
    min_seconds: float = 0.0
    """Least chunk in predicted seconds (used when ``timed``: the speeds were measured)."""
    timed: bool = False
    segments: deque[list[int]] = field(default_factory=deque)
    """Tail units not handed out yet: ``[u0, u1)`` runs in the order they are handed out."""

    @property
    def empty(self) -> bool:
        return not self.segments

    def remaining_cost(self) -> float:
        """Predicted cost of the units not handed out yet."""
        return float(sum(self.prefix[b] - self.prefix[a] for a, b in self.segments))

    def drain(self) -> None:
        """Give up the units not handed out yet (someone else renders them)."""
        self.segments.clear()

    def next_chunk(self, tracer: str) -> UnitRange | None:
        """The next chunk for ``tracer`` (any id: an unknown one counts at the mean speed), or
        None when the tail is used up."""
        if not self.segments:
            return None
        total_speed = sum(self.speeds.values()) or 1.0
        speed = self.speeds.get(tracer, total_speed / max(1, len(self.speeds)))
        share = speed / total_speed
        frame_cost = float(self.prefix[-1])
        target = max(
            self.remaining_cost() * share / self.divisor,
            self.min_chunk * frame_cost * share,
            self.min_seconds * speed if self.timed else 0.0,
        )
        segment = self.segments[0]
        a, b = segment
        # The most units whose predicted cost fits the target, at least one.
        end = int(np.searchsorted(self.prefix, self.prefix[a] + target, side="right")) - 1
        end = min(max(end, a + 1), b)
        if b - end and self.prefix[b] - self.prefix[end] < 0.5 * target:
            end = b  # do not leave a scrap smaller than half a chunk behind
        if end >= b:
            self.segments.popleft()
        else:
            segment[0] = end
        return a, end

    def take_all(self) -> list[UnitRange]:
        """Hand the whole tail out at once: the chunks of a shared pool, which cannot
        know who claims next, so each is sized for the slowest tracer (any tracer that claims
        it finishes it in time; sized for the mean, the last chunks held up the frame when a
        slow tracer took one: 2.02 against 3.15% idle with 128 tracers of speeds 0.5-2,
        ``bench/balance_sim.py --calls --pool``)."""
        slowest = min(self.speeds, key=self.speeds.get) if self.speeds else ""
        chunks = []
        while (chunk := self.next_chunk(slowest)) is not None:
            chunks.append(chunk)
        return chunks


def cut_head(prefix: np.ndarray, a: int, b: int, fraction: float) -> tuple[UnitRange, UnitRange]:
    """(head, rest) of range [a, b): the head holds at most ``fraction`` of its predicted cost,
    the rest sits at the end of the range that gives it more units (cheaper units: finer
    chunks)."""
    if b <= a or fraction >= 1.0:
        return (a, b), (b, b)
    keep = fraction * (prefix[b] - prefix[a])
    first = int(np.searchsorted(prefix, prefix[a] + keep, side="right")) - 1
    last = int(np.searchsorted(prefix, prefix[b] - keep, side="left"))
    first, last = min(max(first, a), b), min(max(last, a), b)
    if last - a > b - first:
        return (last, b), (a, last)
    return (a, first), (first, b)

"""``cost-aware-tail`` and ``cost-aware`` (the default): the cost-aware split with a dynamic
tail (:mod:`cluster.balancing.tail_plan`), handed out in calls or claimed from a shared pool."""

import math
from collections import deque
from collections.abc import Sequence

import numpy as np

from cluster.balancing.base import TracerReport, check_reports, usable
from cluster.balancing.cost_aware import CostAware
from cluster.balancing.tail_plan import TailPlan, UnitRange, cut_head


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
    smoothing step per frame). A report whose seconds are not usable (NaN: units rendered by a
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
        # Predicted seconds of heads not observed yet, oldest first per (tracer, units, spans,
        # u0, u1): with the pipeline, frame N+1 may get the same head as frame N before N is
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
        units: int,
        tracers: Sequence[str],
        pooled: bool = False,
        spans: int = 1,
        claim_seconds: float = 0.0,
    ) -> TailPlan:
        """Heads (one per tracer, in order) and the tail of the next frame. ``pooled``: the
        tail goes to a shared pool (:mod:`worker.line_pool`, :mod:`worker.remote_pool`), where
        a chunk costs a fraction of a Ray call: smaller chunks, and a tail on smaller frames;
        ``claim_seconds``, what one claim costs a tracer, keeps chunks at least twice that."""
        ranges = self.split(units, tracers, spans)
        profile = self.predicted_profile(units, spans)
        prefix = np.concatenate(([0.0], np.cumsum(profile)))
        speeds = self.speeds(tracers)
        timed = all(t in self._work for t in tracers)
        frame_seconds = prefix[-1] / speeds.sum() if timed else math.inf
        fraction = self.head_fraction(frame_seconds, pooled, len(tracers))
        min_lines = min(self.min_lines, self.POOL_MIN_LINES) if pooled else self.min_lines
        if units < min_lines * spans * len(tracers) or not (pooled or self.call_tail):
            fraction = 1.0
        known = self._predictors[0].level is not None
        heads: list[UnitRange] = []
        tail: list[tuple[float, int, int]] = []
        for tracer, speed, (a, b) in zip(tracers, speeds, ranges, strict=True):
            head, rest = cut_head(prefix, a, b, fraction)
            heads.append(head)
            if head[1] > head[0] and known and tracer in self._work:  # a real prediction
                predicted = (prefix[head[1]] - prefix[head[0]]) / speed
                key = (tracer, units, spans, *head)
                queued = self._heads.pop(key, deque())  # re-inserted: the newest is kept
                queued.append(predicted)
                self._heads[key] = queued
            if rest[1] > rest[0]:
                per_unit = (prefix[rest[1]] - prefix[rest[0]]) / (rest[1] - rest[0])
                tail.append((-per_unit, rest[0], rest[1]))
        while len(self._heads) > self.HEADS_KEPT * len(tracers):
            self._heads.pop(next(iter(self._heads)))
        segments = deque([u0, u1] for _, u0, u1 in sorted(tail))  # dearest first
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

    def observe(self, units: int, reports: Sequence[TracerReport], spans: int = 1) -> None:
        check_reports(units, reports, spans)
        work: dict[str, list[float]] = {}
        for r in reports:
            sums = work.setdefault(r.tracer, [0.0, 0.0])
            if r.u1 > r.u0 and usable(r.seconds):
                sums[0] += float(np.sum(r.unit_cost))
                sums[1] += r.seconds
                key = (r.tracer, units, spans, r.u0, r.u1)
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
        self._observe_profile(units, reports, spans)


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

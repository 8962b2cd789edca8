"""The dynamic tail (``cluster.balancing.tail``, ``cluster.balancing.tail_plan``): heads and
chunks partition the frame, chunks shrink and follow the tracers' speeds, the tail's share follows
how well heads were predicted, and the tail absorbs speed changes no static split can
foresee."""

import heapq
import itertools
import math
from collections import deque

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cluster.balancing import CostAware, CostAwareTail, TracerReport, idle_percent, make_balancer
from cluster.balancing.tail_plan import TailPlan
from tests.cluster.test_balance import run_frame, sky_and_ground


def hand_out(plan, ids) -> list[tuple[str, int, int]]:
    """Every chunk of ``plan``, tracers asking in turn."""
    chunks = []
    turn = 0
    while not plan.empty:
        tracer = ids[turn % len(ids)]
        chunks.append((tracer, *plan.next_chunk(tracer)))
        turn += 1
    assert plan.next_chunk(ids[0]) is None
    return chunks


def dynamic_frame(balancer, cost, ids, speeds) -> list[float]:
    """One frame without latency: every tracer renders its head, then asks for chunks until
    the tail is used up; returns each tracer's finishing time (its busy seconds)."""
    plan = balancer.plan(cost.size, ids)
    speed = dict(zip(ids, speeds, strict=True))
    heads = dict(zip(ids, plan.heads, strict=True))
    free = {t: float(cost[y0:y1].sum()) / speed[t] for t, (y0, y1) in heads.items()}
    reports = [
        TracerReport(t, y0, y1, free[t], cost[y0:y1].astype(np.int64))
        for t, (y0, y1) in zip(ids, plan.heads, strict=True)
    ]
    queue = [(free[t], t) for t in ids]
    heapq.heapify(queue)
    while not plan.empty:
        now, tracer = heapq.heappop(queue)
        y0, y1 = plan.next_chunk(tracer)
        seconds = float(cost[y0:y1].sum()) / speed[tracer]
        free[tracer] = now + seconds
        reports.append(TracerReport(tracer, y0, y1, seconds, cost[y0:y1].astype(np.int64)))
        heapq.heappush(queue, (free[tracer], tracer))
    balancer.observe(cost.size, reports)
    return [free[t] for t in ids]


@settings(max_examples=60)
@given(
    height=st.integers(0, 300),
    tracers=st.integers(1, 12),
    seed=st.integers(0, 2**32 - 1),
    frames=st.integers(1, 4),
)
def test_heads_and_chunks_partition_the_frame(height, tracers, seed, frames):
    """Heads lie inside the cost-aware ranges, in order; heads and chunks together cover every
    line exactly once; every chunk has at least one line; the same calls give the same plan."""
    ids = [f"t{i}" for i in range(tracers)]
    a, b = CostAwareTail(), CostAwareTail()
    rng = np.random.default_rng(seed)
    for _ in range(frames):
        plan, twin = a.plan(height, ids), b.plan(height, ids)
        ranges = a.split(height, ids)
        assert plan.heads == twin.heads
        for (h0, h1), (r0, r1) in zip(plan.heads, ranges, strict=True):
            assert r0 <= h0 <= h1 <= r1
        chunks = hand_out(plan, ids)
        assert chunks == hand_out(twin, ids)
        covered = np.zeros(height, int)
        for y0, y1 in [*plan.heads, *((y0, y1) for _, y0, y1 in chunks)]:
            covered[y0:y1] += 1
        assert np.all(covered == 1)
        assert all(y1 > y0 for _, y0, y1 in chunks)
        cost = rng.integers(0, 1000, height) * (rng.random(height) < 0.7)
        heads = [(t, y0, y1) for t, (y0, y1) in zip(ids, plan.heads, strict=True)]
        reports = [
            TracerReport(t, y0, y1, float(rng.random()), cost[y0:y1].astype(np.int64))
            for t, y0, y1 in [*heads, *chunks]
        ]
        a.observe(height, reports)
        b.observe(height, reports)


def test_the_head_holds_the_fraction_and_the_tail_sits_on_the_cheap_side():
    """With a known profile, a head holds at most ``fraction`` of its range's predicted cost
    (within one line), and the rest lies at the end of the range with more lines: the sky."""
    cost = sky_and_ground(200)
    balancer = CostAwareTail(fraction=0.8)
    for _ in range(3):
        run_frame(balancer, cost, ["a", "b"], [1.0, 1.0])
    plan = balancer.plan(200, ["a", "b"])
    ranges = balancer.split(200, ["a", "b"])
    prefix = plan.prefix
    for (h0, h1), (r0, r1) in zip(plan.heads, ranges, strict=True):
        share = (prefix[h1] - prefix[h0]) / (prefix[r1] - prefix[r0])
        line = np.max(np.diff(prefix[r0 : r1 + 1])) / (prefix[r1] - prefix[r0])
        assert 0.8 - line <= share <= 0.8 + 1e-9
    (a0, a1), _ = plan.heads
    assert a0 > 0 and a1 == ranges[0][1]  # tracer a's rest is the sky at the top
    first = plan.segments[0]
    assert first[0] >= 100  # the dearest segment (ground) is handed out first


def one_segment_plan(lines: int, speeds: dict[str, float], min_chunk: float = 0.0) -> TailPlan:
    """A plan whose whole frame of ``lines`` equal lines (cost 10 each) is the tail."""
    prefix = np.arange(lines + 1) * 10.0
    heads = [(0, 0)] * len(speeds)
    return TailPlan(
        list(speeds), heads, prefix, speeds, 2.0, min_chunk, segments=deque([[0, lines]])
    )


def test_chunks_shrink_and_a_faster_tracer_gets_more():
    """Guided self-scheduling: a chunk is the remaining tail times the tracer's speed share
    over the divisor (at least one line, or the least chunk), so a tracer three times as fast
    gets three times the lines and chunks shrink as the tail is used up."""
    speeds = {"slow": 1.0, "fast": 3.0}
    first_slow = one_segment_plan(1000, speeds).next_chunk("slow")
    first_fast = one_segment_plan(1000, speeds).next_chunk("fast")
    assert first_slow == (0, 125) and first_fast == (0, 375)  # 1000 x 1/4 / 2, 1000 x 3/4 / 2
    plan = one_segment_plan(1000, speeds)
    sizes = []
    while not plan.empty:
        remaining = plan.remaining_cost() / 10
        y0, y1 = plan.next_chunk("slow")
        assert y1 - y0 == max(1, int(remaining / 8)) or y1 == 1000  # or the last scrap
        sizes.append(y1 - y0)
    assert sizes[:-1] == sorted(sizes[:-1], reverse=True)  # shrinking, but for the last scrap
    assert sizes[0] > sizes[-2] and min(sizes) >= 1
    floored = one_segment_plan(1000, speeds, min_chunk=0.1)
    floored.segments[0][0] = 900  # 100 lines left: the least chunk, 10% of 1000 x 1/4
    assert floored.next_chunk("slow") == (900, 925)


def test_the_tail_share_follows_the_prediction_error():
    """Half the frame is the tail before anything is known; on a static profile with exact
    speeds the tail shrinks to ``MIN_TAIL``; with speeds that jump by 10% from frame to frame
    (fixed seed) it stays near ``Z`` times their spread."""
    cost = sky_and_ground(300)
    exact = CostAwareTail()
    assert exact.head_fraction() == pytest.approx(1 - CostAwareTail.FIRST_TAIL)
    for _ in range(30):
        dynamic_frame(exact, cost, ["a", "b"], [1.0, 2.0])
    assert exact.head_fraction() == pytest.approx(1 - CostAwareTail.MIN_TAIL)
    noisy = CostAwareTail()
    rng = np.random.default_rng(7)
    for _ in range(60):
        speeds = np.array([1.0, 2.0]) * np.exp(0.1 * rng.normal(size=2))
        dynamic_frame(noisy, cost, ["a", "b"], speeds)
    tail = 1.0 - noisy.head_fraction()
    # rms of the relative head error is about 0.1 to 0.14 (the speed of one frame against a
    # smoothed mean); the smoothed estimate over ~10 frames stays within a factor 2 of that.
    assert CostAwareTail.Z * 0.05 < tail < CostAwareTail.Z * 0.3
    # The same error with 128 tracers: the tail covers the slowest of 128 heads, about
    # sqrt(2 ln 128) = 3.1 error widths instead of Z = 1.5 (up to the pooled cap).
    many = 1.0 - noisy.head_fraction(pooled=True, tracers=128)
    assert many == pytest.approx(min(tail * math.sqrt(2 * math.log(128)) / 1.5, 0.3))
    assert 1.0 - noisy.head_fraction(pooled=True, tracers=2) == pytest.approx(max(tail, 0.1))


def test_no_tail_when_heads_miss_by_less_than_a_few_calls():
    """Two tracers of 50 ms per frame whose heads are predicted within 1% (0.5 ms): the tail
    would cost more calls than it saves, so the plan is the plain cost-aware split; at 30%
    (about 15 ms, over ``CALLS_WORTH`` calls of ``CALL_SECONDS``) the tail comes back."""
    cost = sky_and_ground(300)
    scale = float(cost.sum()) / 0.1  # speed (cost per second) of a 0.1 s frame per tracer
    balancer = CostAwareTail()
    rng = np.random.default_rng(5)
    for _ in range(30):
        speeds = scale * np.array([1.0, 1.0]) * np.exp(0.005 * rng.normal(size=2))
        dynamic_frame(balancer, cost, ["a", "b"], speeds)
    plan = balancer.plan(300, ["a", "b"])
    assert plan.empty and plan.heads == balancer.split(300, ["a", "b"])
    for _ in range(30):
        speeds = scale * np.array([1.0, 1.0]) * np.exp(0.3 * rng.normal(size=2))
        dynamic_frame(balancer, cost, ["a", "b"], speeds)
    assert not balancer.plan(300, ["a", "b"]).empty


def test_a_pooled_plan_keeps_a_tail_where_a_call_plan_has_none():
    """Heads predicted within 0.5%: a tail in calls would not pay (no tail), but a pooled tail
    costs microseconds per chunk, so the pooled plan keeps at least ``POOL_MIN_TAIL`` in
    chunks down to ``POOL_MIN_SECONDS``; ``cost-aware`` keeps a tail only when pooled."""
    cost = sky_and_ground(300)
    scale = float(cost.sum()) / 0.1
    rng = np.random.default_rng(5)
    tail, default = CostAwareTail(), make_balancer("cost-aware")
    for _ in range(30):
        speeds = scale * np.array([1.0, 1.0]) * np.exp(0.005 * rng.normal(size=2))
        dynamic_frame(tail, cost, ["a", "b"], speeds)
        dynamic_frame(default, cost, ["a", "b"], speeds)
    assert tail.plan(300, ["a", "b"]).empty
    assert default.plan(300, ["a", "b"]).empty
    for balancer in (tail, default):
        plan = balancer.plan(300, ["a", "b"], pooled=True)
        share = plan.remaining_cost() / plan.prefix[-1]
        assert CostAwareTail.POOL_MIN_TAIL * 0.9 <= share <= CostAwareTail.POOL_MAX_TAIL * 1.1
        chunks = plan.take_all()
        assert plan.empty and len(chunks) >= 5
        speed = float(balancer.speeds(["a"])[0])
        smallest = min(plan.prefix[b] - plan.prefix[a] for a, b in chunks) / speed
        assert smallest < 4 * CostAwareTail.POOL_MIN_SECONDS  # far below a call's 10 ms floor


def test_heads_planned_twice_before_an_observation_keep_both_predictions():
    """With the pipeline, frame N+1 is planned before frame N is observed and may get the same
    heads: both predictions are kept and matched to the frames in order."""
    cost = sky_and_ground(300)
    balancer = CostAwareTail(fraction=0.8)
    dynamic_frame(balancer, cost, ["a", "b"], [1e6, 1e6])
    first, second = balancer.plan(300, ["a", "b"]), balancer.plan(300, ["a", "b"])
    assert first.heads == second.heads
    keys = [("a", 300, 1, *first.heads[0]), ("b", 300, 1, *first.heads[1])]
    assert all(len(balancer._heads[key]) == 2 for key in keys)
    reports = [
        TracerReport(t, y0, y1, 0.01, cost[y0:y1].astype(np.int64))
        for t, (y0, y1) in zip(["a", "b"], first.heads, strict=True)
    ]
    balancer.observe(300, reports)
    assert all(len(balancer._heads[key]) == 1 for key in keys)
    balancer.observe(300, reports)
    assert not any(key in balancer._heads for key in keys)


def test_several_reports_per_tracer_give_the_speed_of_their_sums():
    """A tracer's heads and chunks count as one measurement: cost over seconds of the frame."""
    cost = np.arange(1, 101, dtype=np.int64)
    one, many = CostAwareTail(), CostAwareTail()
    one.observe(100, [TracerReport("a", 0, 100, 2.0, cost)])
    many.observe(
        100,
        [
            TracerReport("a", 0, 30, 0.3, cost[:30]),
            TracerReport("a", 30, 90, 1.2, cost[30:90]),
            TracerReport("a", 90, 100, 0.5, cost[90:]),
        ],
    )
    assert many.speeds(["a"])[0] == pytest.approx(one.speeds(["a"])[0])
    nan_only = CostAwareTail()
    nan_only.observe(100, [TracerReport("a", 0, 100, float("nan"), cost)])
    assert nan_only.speeds(["a", "b"]).tolist() == [1.0, 1.0]  # nothing measured
    assert nan_only.predicted_profile(100)[-1] > nan_only.predicted_profile(100)[0]


def test_the_tail_absorbs_speed_changes_a_static_split_cannot_foresee():
    """Two tracers whose speeds jump by 8% (lognormal sigma) every frame, fixed seed, no call
    overhead: the static cost-aware split idles about as much as the jumps (3-5%), the tail
    a fraction of that (under a third)."""
    cost = sky_and_ground(400)
    rng = np.random.default_rng(3)
    jumps = np.exp(0.08 * rng.normal(size=(40, 2)))
    static, tail = make_balancer("cost-aware-static"), make_balancer("cost-aware-tail")
    idle_static, idle_tail = [], []
    for j in jumps:
        speeds = np.array([1.0, 1.7]) * j
        idle_static.append(idle_percent(run_frame(static, cost, ["a", "b"], speeds)[1]))
        idle_tail.append(idle_percent(dynamic_frame(tail, cost, ["a", "b"], speeds)))
    assert isinstance(static, CostAware) and static.plan(400, ["a", "b"]) is None  # no tail
    assert np.mean(idle_static[5:]) > 2.0
    assert np.mean(idle_tail[5:]) < np.mean(idle_static[5:]) / 3


def test_many_pipelined_tracers_keep_every_head_prediction():
    """128 tracers, frame N+1 planned before N is observed: every head of N is still matched
    to its prediction, so the heads' error (and the tail's size) is learned. (Predictions
    used to be capped at 64 whatever the tracer count: with 128 tracers none survived.)"""
    tracers = [f"t{i:03d}" for i in range(128)]
    cost = sky_and_ground(128 * 8)
    balancer = CostAwareTail(z=1.0)
    dynamic_frame(balancer, cost, tracers, [1e6] * 128)
    speeds = balancer.speeds(tracers)
    first = balancer.plan(cost.size, tracers, pooled=True)
    balancer.plan(cost.size, tracers, pooled=True)  # the next frame, before the first is seen
    slower = 1.3  # every head took 30% longer than predicted
    reports = [
        TracerReport(
            t,
            a,
            b,
            slower * float(first.prefix[b] - first.prefix[a]) / v,
            cost[a:b].astype(np.int64),
        )
        for t, v, (a, b) in zip(tracers, speeds, first.heads, strict=True)
        if b > a
    ]
    balancer.observe(cost.size, reports)
    assert balancer._error2 is not None and math.sqrt(balancer._error2) > 0.2


def test_pooled_chunks_are_sized_for_the_slowest_tracer():
    """Whoever claims a pooled chunk, the slowest tracer included, must finish it in time: the
    first chunk is the remaining tail x the slowest tracer's share of the speed / divisor."""
    prefix = np.arange(1001, dtype=np.float64)  # every line costs 1
    plan = TailPlan(
        tracers=["slow", "fast"],
        heads=[(0, 0), (0, 0)],
        prefix=prefix,
        speeds={"slow": 1.0, "fast": 4.0},
        divisor=2.0,
        segments=deque([[0, 1000]]),
    )
    chunks = plan.take_all()
    assert chunks[0] == (0, 100)  # 1000 x 1/5 / 2, not the mean tracer's 1000 x 1/2 / 2
    assert [b - a for a, b in chunks] == sorted((b - a for a, b in chunks), reverse=True)
    assert chunks[-1][1] == 1000 and all(a == b for (_, a), (b, _) in itertools.pairwise(chunks))


def test_a_head_planned_every_frame_outlives_stale_predictions():
    """Predictions are dropped oldest-used first: a head that recurs every frame (the same
    range, pipelined) is kept while heads of a layout no longer used are dropped."""
    cost = sky_and_ground(300)
    balancer = CostAwareTail(fraction=0.8)
    dynamic_frame(balancer, cost, ["a", "b"], [1e6, 1e6])
    balancer.plan(300, ["a", "b"])  # heads pending, never observed
    for _ in range(CostAwareTail.HEADS_KEPT * 2):  # other frame sizes come and go
        balancer.plan(150 + len(balancer._heads), ["a", "b"])
        balancer.plan(300, ["a", "b"])
    assert len(balancer._heads) <= CostAwareTail.HEADS_KEPT * 2
    live = [key for key in balancer._heads if key[1] == 300]
    rounds = 1 + CostAwareTail.HEADS_KEPT * 2  # every prediction of it is still queued
    assert len(live) == 2 and all(len(balancer._heads[key]) == rounds for key in live)

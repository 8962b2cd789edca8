"""Workload balancers (``cluster.balancing``): every split is a valid partition, each balancer
does what its formula says, ``cost-aware`` converges, and tracers may come and go."""

import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cluster.balancing import (
    BALANCERS,
    Balancer,
    CostAware,
    Perfect,
    PerfectSmooth,
    RobinHood,
    TracerReport,
    idle_percent,
    make_balancer,
    min_max_cuts,
)

NAMES = sorted(BALANCERS)


def assert_partition(ranges, height: int, tracers: int) -> None:
    """One range per tracer, in order, contiguous, covering [0, height) exactly."""
    assert len(ranges) == tracers
    position = 0
    for y0, y1 in ranges:
        assert isinstance(y0, int) and isinstance(y1, int)
        assert y0 == position and y0 <= y1
        position = y1
    assert position == height


def run_frame(balancer, cost: np.ndarray, ids, speeds, overhead: float = 0.0):
    """Split, time each tracer as cost / speed (+ overhead if it has lines), observe; returns
    (ranges, seconds)."""
    ranges = balancer.split(cost.size, ids)
    assert_partition(ranges, cost.size, len(ids))
    seconds, reports = [], []
    for tracer, speed, (y0, y1) in zip(ids, speeds, ranges, strict=True):
        t = float(cost[y0:y1].sum()) / speed + (overhead if y1 > y0 else 0.0)
        seconds.append(t)
        reports.append(TracerReport(tracer, y0, y1, t, cost[y0:y1].astype(np.int64)))
    balancer.observe(cost.size, reports)
    return ranges, seconds


def sky_and_ground(height: int) -> np.ndarray:
    """A frame like the recorded orbits: cheap sky above, dear and uneven geometry below."""
    y = np.arange(height)
    cost = np.where(y < height // 2, 5, 200 + 800 * np.sin(np.pi * y / height) ** 2)
    return cost.astype(np.int64)


# --- idle_percent ------------------------------------------------------------------------------


def test_idle_percent_known_values():
    assert idle_percent([1.0, 1.0]) == 0.0
    assert idle_percent([1.0, 0.5]) == pytest.approx(25.0)
    assert idle_percent([2.0, 1.0, 1.0]) == pytest.approx(100.0 * 2.0 / 6.0)
    assert idle_percent([3.0, 0.0, 0.0, 0.0]) == pytest.approx(75.0)
    assert idle_percent([]) == 0.0
    assert idle_percent([0.0, 0.0]) == 0.0
    with pytest.raises(ValueError):
        idle_percent([1.0, -1.0])
    with pytest.raises(ValueError):
        idle_percent([1.0, math.nan])


# --- every balancer ----------------------------------------------------------------------------


def test_make_balancer_names_the_choices():
    for name in NAMES:
        assert make_balancer(name).name == name
    assert set(NAMES) == {
        "none",
        "robin-hood",
        "perfect",
        "perfect-smooth",
        "cost-aware-static",
        "cost-aware",
        "cost-aware-tail",
    }
    with pytest.raises(ValueError, match="bogus") as error:
        make_balancer("bogus")
    for name in NAMES:
        assert name in str(error.value)


frames_strategy = st.lists(
    st.tuples(
        st.integers(0, 300),  # height
        st.lists(st.integers(0, 11), min_size=1, max_size=12, unique=True),  # tracer ids
        st.integers(0, 2**32 - 1),  # seed of costs and times
    ),
    min_size=1,
    max_size=5,
)


@pytest.mark.parametrize("name", NAMES)
@settings(max_examples=40)
@given(frames=frames_strategy)
def test_every_split_is_a_partition(name, frames):
    """Random heights (also smaller than the tracer count, and 0), tracers joining and leaving,
    zero costs and zero or huge times: every split is valid, and a second balancer fed the same
    calls gives the same splits."""
    a, b = make_balancer(name), make_balancer(name)
    for height, id_numbers, seed in frames:
        ids = [f"tracer-{n}" for n in id_numbers]
        ranges = a.split(height, ids)
        assert ranges == b.split(height, ids)
        assert_partition(ranges, height, len(ids))
        rng = np.random.default_rng(seed)
        cost = rng.integers(0, 1000, height) * (rng.random(height) < 0.7)
        reports = [
            TracerReport(
                t,
                y0,
                y1,
                float(rng.choice([0.0, 1e-9, rng.random(), 1e6])),
                cost[y0:y1].astype(np.int64),
            )
            for t, (y0, y1) in zip(ids, ranges, strict=True)
        ]
        a.observe(height, reports)
        b.observe(height, reports)
    assert a.split(97, ["x", "tracer-3"]) == b.split(97, ["x", "tracer-3"])


@pytest.mark.parametrize("name", NAMES)
def test_one_tracer_gets_everything(name):
    balancer = make_balancer(name)
    for _ in range(3):
        ranges, _ = run_frame(balancer, sky_and_ground(50), ["only"], [1.0])
        assert ranges == [(0, 50)]


@pytest.mark.parametrize("name", NAMES)
def test_more_tracers_than_lines(name):
    balancer = make_balancer(name)
    ids = [f"t{i}" for i in range(7)]
    for _ in range(4):
        ranges, _ = run_frame(balancer, np.array([3, 0, 9]), ids, [1, 2, 1, 0.5, 1, 1, 3])
        assert sum(y1 > y0 for y0, y1 in ranges) <= 3


@pytest.mark.parametrize("name", NAMES)
def test_inconsistent_reports_are_refused(name):
    balancer = make_balancer(name)
    with pytest.raises(ValueError, match="unit costs"):
        balancer.observe(10, [TracerReport("a", 0, 10, 1.0, np.ones(9, np.int64))])
    with pytest.raises(ValueError, match="not in"):
        balancer.observe(10, [TracerReport("a", 5, 11, 1.0, np.ones(6, np.int64))])
    with pytest.raises(ValueError, match="distinct"):
        balancer.split(10, ["a", "a"])
    with pytest.raises(ValueError, match="at least one"):
        balancer.split(10, [])


# --- robin hood --------------------------------------------------------------------------------


def test_robin_hood_moves_one_unit_from_the_last_to_the_first():
    balancer = RobinHood()  # 1% of 40 lines: the step is one line
    ids = ["a", "b", "c", "d"]
    assert balancer.split(40, ids) == [(0, 10), (10, 20), (20, 30), (30, 40)]
    reports = [
        TracerReport(t, y0, y1, s, np.ones(y1 - y0, np.int64))
        for t, (y0, y1), s in zip(ids, balancer.split(40, ids), [2.0, 1.0, 3.0, 0.5], strict=True)
    ]
    balancer.observe(40, reports)
    # c finished last, d first: c gives d one line; a and b keep theirs.
    assert balancer.split(40, ids) == [(0, 10), (10, 20), (20, 29), (29, 40)]

    wider = RobinHood(step=3)
    wider.observe(40, reports)
    assert wider.split(40, ids) == [(0, 10), (10, 20), (20, 27), (27, 40)]
    with pytest.raises(ValueError):
        RobinHood(step=0)
    assert [RobinHood().step_units(h) for h in (10, 96, 480, 1080)] == [1, 1, 5, 11]


def test_robin_hood_ignores_tracers_without_a_time():
    balancer = RobinHood(step=2)
    ones = np.ones(10, np.int64)
    balancer.observe(
        30,
        [
            TracerReport("a", 0, 10, math.nan, ones),
            TracerReport("b", 10, 20, 2.0, ones),
            TracerReport("c", 20, 30, 1.0, ones),
        ],
    )
    assert balancer.split(30, ["a", "b", "c"]) == [(0, 10), (10, 18), (18, 30)]


def test_robin_hood_gives_no_more_than_it_has_and_handles_newcomers():
    balancer = RobinHood(step=5)
    balancer.observe(
        10,
        [
            TracerReport("slow", 0, 2, 9.0, np.ones(2, np.int64)),
            TracerReport("fast", 2, 10, 1.0, np.ones(8, np.int64)),
        ],
    )
    assert balancer.split(10, ["slow", "fast"]) == [(0, 0), (0, 10)]
    # A newcomer gets the mean count of the others (5), then all are scaled to the height.
    ranges = balancer.split(20, ["slow", "fast", "new"])
    assert [y1 - y0 for y0, y1 in ranges] == [0, 13, 7]


# --- perfect -----------------------------------------------------------------------------------


def test_perfect_gives_equal_tracers_equal_lines_and_a_faster_one_more():
    cost = np.full(120, 7)
    equal = Perfect()
    run_frame(equal, cost, ["a", "b", "c"], [1.0, 1.0, 1.0])
    assert equal.split(120, ["a", "b", "c"]) == [(0, 40), (40, 80), (80, 120)]

    faster = Perfect()
    for _ in range(2):
        run_frame(faster, cost, ["slow", "fast"], [1.0, 2.0])
    sizes = [y1 - y0 for y0, y1 in faster.split(120, ["slow", "fast"])]
    assert sizes == [40, 80]


def test_perfect_ignores_line_costs_and_overshoots():
    """All the dear lines at the bottom: perfect's lines-per-second shares move the cut past
    the balanced point, so the next frame is badly balanced (Bikker's 'hick-ups')."""
    cost = np.concatenate([np.full(50, 1), np.full(50, 100)])
    balancer = Perfect()
    run_frame(balancer, cost, ["a", "b"], [1.0, 1.0])
    _, second = run_frame(balancer, cost, ["a", "b"], [1.0, 1.0])
    assert idle_percent(second) > 40.0  # "a" now holds nearly every line, dear ones included
    assert balancer.split(100, ["a", "b"])[0][1] > 50


def test_perfect_keeps_speeds_per_tracer_and_defaults_newcomers_to_the_mean():
    balancer = Perfect()
    cost = np.full(90, 3)
    run_frame(balancer, cost, ["a", "b"], [1.0, 3.0])  # a: 45 lines/45*3 s; b three times faster
    ranges = balancer.split(90, ["b", "new", "a"])  # new gets the mean speed, order is new
    sizes = [y1 - y0 for y0, y1 in ranges]
    assert sizes == pytest.approx([45, 30, 15], abs=1)
    # A tracer that left is forgotten by nobody else's split.
    assert balancer.split(90, ["b"]) == [(0, 90)]


def test_perfect_smooth_moves_shares_by_alpha():
    balancer = PerfectSmooth(alpha=0.5)
    cost = np.full(100, 2)
    run_frame(balancer, cost, ["a", "b"], [1.0, 3.0])
    # From the even start (no history) the first target is taken as is: 25% / 75%.
    assert balancer.split(100, ["a", "b"]) == [(0, 25), (25, 100)]
    # b slows down to a's speed: perfect would jump to 50/50, the average goes halfway.
    run_frame(balancer, cost, ["a", "b"], [1.0, 1.0])
    assert balancer.split(100, ["a", "b"]) == [(0, 38), (38, 100)]
    with pytest.raises(ValueError):
        PerfectSmooth(alpha=0.0)


# --- min-max partition -------------------------------------------------------------------------


def brute_force_bottleneck(cost, speeds) -> float:
    height, best = len(cost), math.inf
    for cuts in itertools.combinations_with_replacement(range(height + 1), len(speeds) - 1):
        edges = [0, *cuts, height]
        best = min(
            best,
            max(
                sum(cost[a:b]) / v
                for (a, b), v in zip(itertools.pairwise(edges), speeds, strict=True)
            ),
        )
    return best


@settings(max_examples=60)
@given(
    cost=st.lists(st.floats(0.01, 100.0), min_size=0, max_size=9),
    speeds=st.lists(st.floats(0.1, 10.0), min_size=1, max_size=4),
)
def test_min_max_cuts_is_optimal(cost, speeds):
    edges = min_max_cuts(cost, speeds)
    assert edges[0] == 0 and edges[-1] == len(cost) and len(edges) == len(speeds) + 1
    assert all(a <= b for a, b in itertools.pairwise(edges))
    worst = max(
        (sum(cost[a:b]) / v for (a, b), v in zip(itertools.pairwise(edges), speeds, strict=True)),
        default=0.0,
    )
    assert worst <= brute_force_bottleneck(cost, speeds) * (1 + 1e-6) + 1e-12


def test_min_max_cuts_spreads_slack_towards_the_proportional_cut():
    """Eight equal lines, three equal tracers: 3/3/2 is optimal, and so is 3/2/3; the cut
    nearest the proportional one (8/3, 16/3 -> 3, 5) wins."""
    assert min_max_cuts([1.0] * 8, [1.0, 1.0, 1.0]) == [0, 3, 5, 8]
    assert min_max_cuts([1.0] * 8, [1.0, 3.0]) == [0, 2, 8]
    with pytest.raises(ValueError):
        min_max_cuts([1.0, 0.0], [1.0])


# --- cost-aware --------------------------------------------------------------------------------


def test_cost_aware_converges_on_a_static_profile():
    """Uneven lines and tracers of speeds 1, 2.5, 0.7: after the first frames the predicted
    times, and so the measured ones, are equal to within a line; none and perfect-smooth do
    much worse on the same frames."""
    cost = sky_and_ground(400)
    speeds = [1.0, 2.5, 0.7]
    ids = ["a", "b", "c"]
    idle = {}
    for name in ("cost-aware", "perfect-smooth", "none"):
        balancer = make_balancer(name)
        idle[name] = [idle_percent(run_frame(balancer, cost, ids, speeds)[1]) for _ in range(8)]
    assert idle["cost-aware"][0] > 20.0  # the even first split
    assert max(idle["cost-aware"][2:]) < 1.0
    assert min(idle["none"]) > 20.0
    assert np.mean(idle["perfect-smooth"][2:]) > 2 * np.mean(idle["cost-aware"][2:])


def test_cost_aware_with_overhead_still_converges():
    """A fixed cost per range (here 5% of a frame) biases every speed estimate alike once the
    times are equal, which does not move the cut."""
    cost = sky_and_ground(300)
    balancer = CostAware()
    ids, speeds = ["a", "b"], [1.0, 3.0]
    overhead = 0.05 * cost.sum() / sum(speeds)
    idle = [idle_percent(run_frame(balancer, cost, ids, speeds, overhead)[1]) for _ in range(8)]
    # The even first split gives "a" only sky: its time is mostly overhead, its speed looks
    # 2.5 times too low. Averaging cost and seconds separately outgrows that in a few frames.
    assert idle[0] > 40.0
    assert max(idle[5:]) < 1.0


def test_cost_aware_newcomer_assumed_at_the_mean_speed():
    balancer = CostAware()
    cost = np.full(100, 10)
    run_frame(balancer, cost, ["a", "b"], [1.0, 3.0])
    np.testing.assert_allclose(balancer.speeds(["a", "b", "new"]), [1.0, 3.0, 2.0], rtol=1e-9)
    # Shares 1 : 2 : 3 of a flat profile (cut at 100/6 and 300/6 lines).
    assert balancer.split(100, ["a", "new", "b"]) == [(0, 17), (17, 50), (50, 100)]
    # "a" leaves: "new" is now assumed as fast as "b", the only other tracer.
    assert balancer.split(100, ["new", "b"]) == [(0, 50), (50, 100)]


def test_cost_aware_handles_zero_costs_zero_seconds_and_new_heights():
    balancer = CostAware()
    zeros = np.zeros(20, np.int64)
    run_frame(balancer, zeros, ["a", "b"], [1.0, 1.0])  # no cost, 0 s: nothing learnt
    assert balancer.speeds(["a"]).tolist() == [1.0]
    assert balancer.split(20, ["a", "b"]) == [(0, 10), (10, 20)]
    # Costs only in the top quarter: the cut moves into it.
    cost = np.concatenate([np.full(5, 100), np.zeros(15, np.int64)])
    run_frame(balancer, cost, ["a", "b"], [1.0, 1.0])
    (_, cut), _ = balancer.split(20, ["a", "b"])
    assert 2 <= cut <= 4
    # A taller frame: the profile is stretched through its prefix sum (dear lines still on top).
    (_, cut), _ = balancer.split(80, ["a", "b"])
    assert 8 <= cut <= 16
    assert balancer.predicted_profile(80).sum() == pytest.approx(
        balancer.predicted_profile(20).sum(), rel=0.05
    )


def test_cost_aware_chooses_a_trend_forecaster_for_a_moving_profile():
    """A dear band sliding down one line per frame: forecasters with a trend predict it,
    the moving averages lag; on a still profile with noise an average is chosen."""
    moving = CostAware()
    for frame in range(30):
        cost = np.full(200, 10)
        cost[40 + frame : 70 + frame] = 1000
        run_frame(moving, cost, ["a", "b", "c"], [1.0, 1.0, 1.0])
    assert CostAware.PREDICTORS[moving.chosen][1] > 0.0

    still = CostAware()
    rng = np.random.default_rng(3)
    for _ in range(30):
        cost = rng.poisson(sky_and_ground(200) / 4.0) + 1
        run_frame(still, cost, ["a", "b", "c"], [1.0, 1.0, 1.0])
    assert CostAware.PREDICTORS[still.chosen] != (1.0, 0.0)
    assert CostAware.PREDICTORS[still.chosen][0] < 1.0


def test_cost_aware_beats_perfect_smooth_on_a_moving_camera():
    """A tiny deterministic simulation: a dear band swinging up and down the frame."""
    rng = np.random.default_rng(7)
    ids, speeds = ["a", "b", "c", "d"], [0.6, 1.0, 1.7, 1.2]
    idle = {"cost-aware": [], "perfect-smooth": []}
    balancers = {name: make_balancer(name) for name in idle}
    for frame in range(40):
        y = np.arange(300)
        centre = 180 + 60 * math.sin(frame / 20.0)  # up to 3 lines a frame
        cost = 5 + 1000 * np.exp(-(((y - centre) / 40.0) ** 2)) + rng.integers(0, 20, 300)
        for name, balancer in balancers.items():
            idle[name].append(
                idle_percent(run_frame(balancer, cost.astype(np.int64), ids, speeds)[1])
            )
    assert np.mean(idle["cost-aware"][3:]) < 4.0
    assert np.mean(idle["cost-aware"][3:]) < 0.5 * np.mean(idle["perfect-smooth"][3:])


def test_cost_aware_behind_a_pipeline():
    """A pipelined coordinator splits frame N+1 before it observes frame N: the balancer still
    converges on a static profile, a frame later."""
    balancer = CostAware()
    cost = sky_and_ground(200)
    ids, speeds = ["a", "b"], [1.0, 2.0]
    pending, idle = [], []
    for _ in range(10):
        ranges = balancer.split(200, ids)
        seconds = [float(cost[y0:y1].sum()) / v for (y0, y1), v in zip(ranges, speeds, strict=True)]
        idle.append(idle_percent(seconds))
        pending.append(
            [
                TracerReport(t, y0, y1, sec, cost[y0:y1].astype(np.int64))
                for t, (y0, y1), sec in zip(ids, ranges, seconds, strict=True)
            ]
        )
        if len(pending) > 1:
            balancer.observe(200, pending.pop(0))
    assert idle[1] > 20.0  # the second frame is split before the first is observed
    assert max(idle[3:]) < 1.0


# --- frames cut into spans of lines (worker.work_units) -----------------------------------------


@pytest.mark.parametrize("name", ["robin-hood", "perfect", "perfect-smooth", "cost-aware-static"])
def test_a_change_of_layout_keeps_equal_tracers_equal(name):
    """Three equal tracers on 480 image lines cut into 2 spans each; one sits a frame out (two
    tracers: whole lines) and comes back: it gets a third again, not a share measured in the
    other layout's units."""
    balancer = make_balancer(name)
    ids = ["a", "b", "c"]
    flat = np.full(960, 3)
    for _ in range(3):
        _split_observe(balancer, flat, ids, spans=2)
    _split_observe(balancer, np.full(480, 6), ["a", "b"], spans=1)
    sizes = [b - a for a, b in balancer.split(960, ids, spans=2)]
    assert sizes == pytest.approx([320, 320, 320], abs=12), sizes


def _split_observe(balancer, cost, ids, spans):
    """A frame of equal-speed tracers (seconds = cost of the range)."""
    ranges = balancer.split(cost.size, ids, spans=spans)
    reports = [
        TracerReport(t, a, b, float(cost[a:b].sum()), cost[a:b].astype(np.int64))
        for t, (a, b) in zip(ids, ranges, strict=True)
    ]
    balancer.observe(cost.size, reports, spans=spans)


def test_cost_aware_resamples_spans_and_lines_apart():
    """A profile whose left half of every line is cheap and right half dear keeps that shape
    when the frame changes height (480 -> 360 lines of 2 spans) or spans (2 -> 4 per line)."""
    balancer = CostAware(predictors=[(1.0, 0.0, 1.0)], blur=0)
    left_right = np.tile([1, 100], 480)
    balancer.observe(960, [TracerReport("a", 0, 960, 1.0, left_right)], spans=2)
    shorter = balancer.predicted_profile(720, spans=2).reshape(360, 2)
    assert np.allclose(shorter, [1 * 480 / 360, 100 * 480 / 360])
    finer = balancer.predicted_profile(1920, spans=4).reshape(480, 4)
    assert np.allclose(finer, [0.5, 0.5, 50, 50])
    whole = balancer.predicted_profile(480, spans=1)
    assert np.allclose(whole, 101)


def test_cost_aware_blurs_over_image_lines_within_a_span():
    """The blur averages each span with the same span of the image lines around it, not with
    its neighbours in the line."""
    balancer = CostAware(predictors=[(1.0, 0.0, 1.0)], blur=1)
    cost = np.zeros((6, 4))
    cost[3, 1] = 300.0
    balancer.observe(24, [TracerReport("a", 0, 24, 1.0, cost.reshape(-1).astype(np.int64))], 4)
    profile = balancer.predicted_profile(24, spans=4).reshape(6, 4)
    floor = profile.min()
    assert np.allclose(profile[2:5, 1], 100.0)
    assert np.allclose(np.delete(profile, 1, axis=1), floor)


def test_reports_must_fit_the_spans():
    with pytest.raises(ValueError, match="spans"):
        CostAware().split(10, ["a"], spans=4)


@pytest.mark.parametrize("name", sorted(BALANCERS))
def test_every_balancer_declares_the_interface(name):
    """Each balancer is a ``Balancer``: a plan (heads and a tail) only from the tail
    balancers, the split alone from the others; only ``cost-aware-tail`` may use the actor
    pool."""
    balancer = make_balancer(name)
    assert isinstance(balancer, Balancer) and balancer.name == name
    plan = balancer.plan(40, ["a", "b"])
    assert (plan is not None) == (name in ("cost-aware", "cost-aware-tail"))
    assert balancer.remote_pool == (name == "cost-aware-tail")

"""Progressive frames: waves of two independent half buffers, sized and stopped by a target
error, a time budget or a sample cap. The rules are checked on :class:`ProgressiveFrame`
alone, with synthetic halves and a fake clock; one render goes through a real coordinator and
must equal the library's render of the same samples."""

import math

import numpy as np
import pytest

from cluster.connect import connect, disconnect
from cluster.coordinator import Coordinator
from cluster.progressive import MAX_WAVE_SPP, Goal, ProgressiveFrame, render_progressive
from cluster.scene_graph import SceneGraph
from tests.worker.test_replica import studio
from tracer.compile import compile_scene
from tracer.error_estimate import rel_mse
from tracer.render import render_image
from tracer.scene_format import override

W, H = 16, 12
MU = 0.5
NOISE = 0.8
"""Per-sample relative noise of the synthetic renderer: a half of n samples has relative sd
NOISE / sqrt(n)."""


class FakeClock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def synthetic_half(spp: int, sample_start: int) -> np.ndarray:
    """A half image of ``spp`` samples: the mean of Gaussian samples around MU, seeded by the
    sample range, so that every range is an independent, reproducible draw."""
    rng = np.random.default_rng(sample_start)
    return MU + MU * NOISE / math.sqrt(spp) * rng.normal(size=(H, W, 3))


def drive(goal: Goal, seconds_per_spp: float = 0.01, clock=None) -> tuple[ProgressiveFrame, list]:
    """Run a frame with the synthetic renderer; each half 'takes' spp x seconds_per_spp."""
    clock = clock or FakeClock()
    progress = ProgressiveFrame(W, H, goal, clock=clock)
    halves = []
    while (half := progress.next_half()) is not None:
        halves.append(half)
        seconds = half.spp * seconds_per_spp
        clock.now += seconds
        progress.add_half(synthetic_half(half.spp, half.sample_start), seconds)
    return progress, halves


def test_halves_are_independent_and_equal():
    """Sample ranges follow each other without gaps or overlaps; B repeats A's count; waves
    double the samples until a half reaches MAX_WAVE_SPP."""
    progress, halves = drive(Goal(max_spp=1024))
    start = 0
    for half in halves:
        assert half.sample_start == start
        start += half.spp
    assert start == progress.spp == 1024
    firsts = [h for h in halves if h.first]
    seconds = [h for h in halves if not h.first]
    assert [h.spp for h in firsts] == [h.spp for h in seconds]
    assert [h.spp for h in firsts][:8] == [1, 1, 2, 4, 8, 16, 32, 64]
    assert max(h.spp for h in halves) == MAX_WAVE_SPP
    assert progress.stopped == "max_spp"
    assert progress.spp_a == progress.spp_b == 512


def test_stops_at_the_target_error():
    """The frame stops after the first wave whose estimate meets the target, and not much past
    what the 1/N law predicts (waves aim at the predicted sample count)."""
    target = 0.02
    progress, _ = drive(Goal(target_error=target))
    assert progress.stopped == "target_error"
    assert progress.error <= target
    assert all(w.error > target for w in progress.waves[:-1])
    # The true error of the mean of Gaussian halves: MU * NOISE / sqrt(spp) relative.
    law = (NOISE / target) ** 2
    assert law / 2 < progress.spp < 2 * law
    true = math.sqrt(rel_mse(progress.image, np.full((H, W, 3), MU)))
    assert true == pytest.approx(progress.error, rel=0.3)


def test_stops_within_the_time_budget():
    """With a cost proportional to samples, the last wave is sized to what is left of the
    budget: the frame ends within it, having used most of it."""
    clock = FakeClock()
    budget = 3.0
    progress, _ = drive(Goal(time_budget=budget), seconds_per_spp=0.01, clock=clock)
    assert progress.stopped == "time_budget"
    assert progress.elapsed <= budget
    assert progress.elapsed > 0.8 * budget
    assert progress.spp == round(progress.elapsed / 0.01)


def test_a_frame_takes_at_least_one_wave():
    """A budget smaller than one wave still gives an image of two samples and an estimate."""
    progress, halves = drive(Goal(time_budget=1e-6), seconds_per_spp=1.0)
    assert len(halves) == 2 and progress.spp == 2
    assert progress.stopped == "time_budget"
    assert progress.error is not None


def test_target_or_budget_whichever_first():
    loose, _ = drive(Goal(target_error=0.2, time_budget=1000.0))
    assert loose.stopped == "target_error"
    tight, _ = drive(Goal(target_error=1e-4, time_budget=2.0))
    assert tight.stopped == "time_budget"


@pytest.mark.parametrize(
    "goal",
    [
        {"target_error": 0.0},
        {"target_error": -1.0},
        {"target_error": math.nan},
        {"time_budget": 0.0},
        {"time_budget": math.inf},
        {"max_spp": 1},
    ],
)
def test_bad_goals_are_refused(goal):
    with pytest.raises(ValueError):
        Goal(**goal)


def test_add_half_checks_its_input():
    progress = ProgressiveFrame(W, H, Goal())
    with pytest.raises(RuntimeError, match="next_half"):
        progress.add_half(np.zeros((H, W, 3)), 0.1)
    progress.next_half()
    with pytest.raises(ValueError, match="shape"):
        progress.add_half(np.zeros((H + 1, W, 3)), 0.1)


@pytest.fixture(scope="module")
def coordinator():
    connection = connect(num_cpus=2)
    coordinator = Coordinator(SceneGraph(studio()), tracers=1)
    yield coordinator
    coordinator.close()
    if connection.started:
        disconnect()


def test_through_the_coordinator(coordinator):
    """Waves through tracer actors: the image is the mean of samples [0, spp), which the
    library renders in one call (equal up to float32 rounding of the half means), and the
    reported error is the estimate from the two halves."""
    state = coordinator.graph.state
    progress = render_progressive(coordinator, Goal(max_spp=12))
    assert progress.stopped == "max_spp" and progress.spp == 12
    expected = render_image(compile_scene(state), settings=override(state.render, spp=12))[0]
    np.testing.assert_allclose(progress.image, expected, rtol=1e-5, atol=1e-6)
    assert progress.error > 0.0
    reached = render_progressive(coordinator, Goal(target_error=progress.error * 1.5))
    assert reached.stopped == "target_error" and reached.spp <= 12

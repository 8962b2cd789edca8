"""Progressive frames: waves of independent parts, sized and stopped by a target error, a time
budget or a sample cap. The rules are checked on :class:`ProgressiveFrame`
alone, with synthetic parts and a fake clock; one render goes through a real coordinator and
must equal the library's render of the same samples."""

import math

import numpy as np
import pytest

from cluster.connect import connect, disconnect
from cluster.coordinator import Coordinator
from cluster.progressive import (
    MAX_PART_SPP,
    DenoisedTarget,
    Goal,
    Part,
    ProgressiveFrame,
    SpotCheck,
    progressive_step,
    render_progressive,
)
from cluster.scene_graph import SceneGraph
from tests.worker.test_replica import studio
from tracer.accuracy.error_estimate import PARTS, SPOT_CHECK_FACTOR, rel_mse
from tracer.accuracy.spot_check import render_spot_checks
from tracer.compiled.scene import compile_scene
from tracer.integrators import aov
from tracer.render import render_image, render_pixels
from tracer.request import FrameRequest
from tracer.scene.format import override

W, H = 16, 12
MU = 0.5
NOISE = 0.8
"""Per-sample relative noise of the synthetic renderer: a part of n samples has relative sd
NOISE / sqrt(n)."""


class FakeClock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def synthetic_part(spp: int, sample_start: int, height: int = H, width: int = W) -> np.ndarray:
    """A part image of ``spp`` samples: the mean of Gaussian samples around MU, seeded by the
    sample range, so that every range is an independent, reproducible draw."""
    rng = np.random.default_rng(sample_start)
    return MU + MU * NOISE / math.sqrt(spp) * rng.normal(size=(height, width, 3))


def drive(goal: Goal, seconds_per_spp: float = 0.01, clock=None) -> tuple[ProgressiveFrame, list]:
    """Run a frame with the synthetic renderer; each part 'takes' spp x seconds_per_spp."""
    clock = clock or FakeClock()
    progress = ProgressiveFrame(W, H, goal, clock=clock)
    rendered = []
    while (part := progress.next_part()) is not None:
        rendered.append(part)
        seconds = part.spp * seconds_per_spp
        clock.now += seconds
        progress.add_part(synthetic_part(part.spp, part.sample_start), seconds)
    return progress, rendered


def test_parts_are_independent_and_equal():
    """Sample ranges follow each other without gaps or overlaps; every part of a wave has the
    first part's count; waves double the samples until a part reaches MAX_PART_SPP."""
    progress, parts = drive(Goal(max_spp=1024))
    start = 0
    for part in parts:
        assert part.sample_start == start
        start += part.spp
    assert start == progress.spp == 1024
    assert [p.index for p in parts] == list(range(PARTS)) * (len(parts) // PARTS)
    waves = [parts[i : i + PARTS] for i in range(0, len(parts), PARTS)]
    assert all(len({p.spp for p in wave}) == 1 for wave in waves)
    assert [wave[0].spp for wave in waves][:7] == [1, 1, 2, 4, 8, 16, 32]
    assert max(p.spp for p in parts) == MAX_PART_SPP  # the cap is reached, never passed
    assert progress.stopped == "max_spp"
    assert progress.part_spp * PARTS == 1024


def test_stops_at_the_target_error():
    """The frame stops after the first wave whose estimate meets the target, and not much past
    what the 1/N law predicts (waves aim at the predicted sample count)."""
    target = 0.02
    progress, _ = drive(Goal(target_error=target))
    assert progress.stopped == "target_error"
    assert progress.error <= target
    assert all(w.error > target for w in progress.waves[:-1])
    # The true error of the mean of Gaussian parts: MU * NOISE / sqrt(spp) relative.
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
    """A budget smaller than one wave still gives an image of one sample per part and an
    estimate."""
    progress, parts = drive(Goal(time_budget=1e-6), seconds_per_spp=1.0)
    assert len(parts) == PARTS and progress.spp == PARTS
    assert progress.stopped == "time_budget"
    assert progress.error is not None


def test_a_target_waits_for_an_estimate():
    """While the estimate says "not estimable yet" (None), a frame with a target error keeps
    sampling, and the waves keep doubling: a renderer whose parts 0 and 2 each saw one
    bright outlier, in two pixels far apart, on an otherwise noiseless image (two pixels
    alone decide whether they are fireflies or lights smaller than a pixel)."""
    progress = ProgressiveFrame(W, H, Goal(target_error=0.5, max_spp=64))
    while (part := progress.next_part()) is not None:
        image = np.full((H, W, 3), MU)
        if part.index in (0, 2):  # one sample of 1000 in the part
            image[4 * part.index, 6 * part.index] = 1000.0 / part.spp
        progress.add_part(image, 0.1)
    assert [w.error for w in progress.waves] == [None] * len(progress.waves)
    assert [w.spp for w in progress.waves] == [4, 8, 16, 32, 64]
    assert progress.stopped == "max_spp"


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
        {"max_spp": 3},  # a wave is four parts of at least one sample
    ],
)
def test_bad_goals_are_refused(goal):
    with pytest.raises(ValueError):
        Goal(**goal)


def test_add_part_checks_its_input():
    progress = ProgressiveFrame(W, H, Goal())
    with pytest.raises(RuntimeError, match="next_part"):
        progress.add_part(np.zeros((H, W, 3)), 0.1)
    progress.next_part()
    with pytest.raises(ValueError, match="shape"):
        progress.add_part(np.zeros((H + 1, W, 3)), 0.1)


def test_aovs_of_the_parts_blend_by_their_samples():
    """Parts that carry AOVs give the frame the sample-weighted mean of them (spot checks
    leave them alone), but the ids of the first part (every pixel's sample 0); a part without
    AOVs after parts with them is refused."""
    progress = ProgressiveFrame(W, H, Goal(max_spp=64))
    total, spp, first = np.zeros((H, W, aov.CHANNELS)), 0, None
    while (part := progress.next_part()) is not None:
        if isinstance(part, SpotCheck):
            progress.add_spot_checks(np.zeros((0, 2), np.int64), np.zeros((PARTS, 0, 3)), 0.0)
            continue
        channels = np.random.default_rng(part.sample_start).uniform(size=(H, W, aov.CHANNELS))
        channels[..., aov.IDS] = np.random.default_rng(part.sample_start).integers(-1, 9, (H, W, 2))
        first = channels if first is None else first
        total += channels * part.spp
        spp += part.spp
        progress.add_part(synthetic_part(part.spp, part.sample_start), 0.01, aov=channels)
    assert progress.spp == spp == 64 and len(progress.waves) > 1
    means = [c for c in range(aov.CHANNELS) if c not in (aov.OBJECT_ID, aov.MATERIAL_ID)]
    assert np.allclose(progress.aov[..., means], total[..., means] / spp, atol=1e-6)
    assert np.array_equal(progress.aov[..., aov.IDS], first[..., aov.IDS])
    assert ProgressiveFrame(W, H, Goal()).aov is None
    mixed = ProgressiveFrame(W, H, Goal())
    mixed.next_part()
    mixed.add_part(synthetic_part(1, 0), 0.01, aov=np.zeros((H, W, aov.CHANNELS)))
    mixed.next_part()
    with pytest.raises(ValueError, match="carries AOVs"):
        mixed.add_part(synthetic_part(1, 1), 0.01)


def test_a_denoised_target_takes_the_denoised_estimate_once_parts_are_deep_enough():
    """With a ``DenoisedTarget``, waves whose parts have ``MIN_PART_SPP`` samples or more take
    the estimate of the denoised mean (``denoise_and_estimate`` on the same parts and guides),
    the earlier ones the beauty's; the summary says which."""
    from tracer.accuracy.denoised_error import MIN_PART_SPP, denoise_and_estimate

    target = DenoisedTarget("fast", prefilter=False)
    progress = ProgressiveFrame(W, H, Goal(target_error=1e-4, max_spp=128), denoised=target)
    channels = np.zeros((H, W, aov.CHANNELS), np.float32)
    channels[..., aov.ALBEDO : aov.ALBEDO + 3] = 0.5
    channels[..., aov.NORMAL + 2] = 1.0
    while (part := progress.next_part()) is not None:
        if isinstance(part, SpotCheck):
            progress.add_spot_checks(np.zeros((0, 2), np.int64), np.zeros((PARTS, 0, 3)), 0.0)
            continue
        radiance = np.abs(synthetic_part(part.spp, part.sample_start))  # radiance is >= 0
        progress.add_part(radiance, 0.01, aov=channels)
    assert progress.spp == 128 and progress.stopped == "max_spp"
    for wave in progress.waves:
        deep = wave.spp // PARTS >= MIN_PART_SPP
        assert wave.error_of == ("denoised" if deep else "beauty"), wave
    parts = progress.sums / progress.part_spp
    albedo = channels[..., aov.ALBEDO : aov.ALBEDO + 3]
    normal = channels[..., aov.NORMAL : aov.NORMAL + 3]
    _, expected = denoise_and_estimate(
        parts, progress.part_spp, albedo, normal, "fast", False, seed=progress.spp
    )
    assert progress.waves[-1].error == expected and expected is not None
    assert progress.summary()["error_of"] == "denoised"
    assert DenoisedTarget.of(override(studio().render, denoise="fast"), Goal()) is None
    with_target = DenoisedTarget.of(override(studio().render, denoise="high"), Goal(0.1))
    assert with_target == DenoisedTarget("high", prefilter=True)  # auto, unresolved: on


def lit_pixel_wave(progress: ProgressiveFrame, width: int, height: int) -> None:
    """Render a wave in which part 2 alone saw a light smaller than a pixel at (5, 7) (one
    sample of 1000), on a slightly noisy image."""
    rng = np.random.default_rng(progress.spp)
    for _ in range(PARTS):
        part = progress.next_part()
        assert isinstance(part, Part)
        image = MU + 0.01 * rng.normal(size=(height, width, 3))
        image[5, 7] = 0.0
        if part.index == 2:
            image[5, 7] = 1000.0 / part.spp
        progress.add_part(image, 0.1)


def test_a_wave_ends_with_spot_checks():
    """A frame of 32x24 pixels may spot-check one pixel at 4 spp. After the wave's fourth part
    it names the pixel that one part alone saw lit, to 64 times the frame's samples, and waits
    for it: no part until then. Without its check the error is not estimable; a check that
    finds the pixel's value gives the estimate, and the wave records the pixel checked. The
    next wave's check of it only tops its samples up."""
    width, height = 32, 24
    progress = ProgressiveFrame(width, height, Goal(max_spp=64))
    lit_pixel_wave(progress, width, height)
    check = progress.next_part()
    assert isinstance(check, SpotCheck)
    need = SPOT_CHECK_FACTOR * progress.spp // PARTS
    assert check.pixels.tolist() == [[5, 7]]
    assert check.part_start.tolist() == [0] and check.part_spp.tolist() == [need]
    assert progress.next_part() is check and not progress.waves
    with pytest.raises(RuntimeError, match="pending part"):
        progress.add_part(np.zeros((height, width, 3)), 0.1)
    light = 1000.0 / progress.spp  # the light's value, as the mean saw it
    spread = (1.0 + 0.01 * np.arange(PARTS))[:, None, None]
    progress.add_spot_checks(check.pixels, np.full((PARTS, 1, 3), light) * spread, 1.0)
    wave = progress.waves[-1]
    assert wave.checked == 1 and wave.error is not None
    assert progress.error == pytest.approx(wave.error)
    lit_pixel_wave(progress, width, height)
    again = progress.next_part()
    assert again.pixels.tolist() == [[5, 7]]
    assert again.part_start.tolist() == [need] and again.part_spp.tolist() == [need]


def test_spot_checks_count_in_the_time_budget():
    """The checks' seconds count in their wave's: with checks that cost as much per sample as
    the parts (at most an eighth of the samples), a budget stops the frame at fewer samples
    than free checks would, and still within a quarter past the budget."""
    width, height = 32, 24
    per_sample = 0.01 / (width * height)  # seconds per pixel sample of the parts
    stops = []
    for check_cost in (0.0, per_sample):
        clock = FakeClock()
        progress = ProgressiveFrame(width, height, Goal(time_budget=6.0), clock=clock)
        while (step := progress.next_part()) is not None:
            if isinstance(step, Part):
                seconds = step.spp * width * height * per_sample
                clock.now += seconds
                image = synthetic_part(step.spp, step.sample_start, height, width)
                image[5, 7] = 0.0 if step.index != 2 else 1000.0 / step.spp
                progress.add_part(image, seconds)
                continue
            seconds = step.samples * check_cost
            clock.now += seconds
            checked = np.full((PARTS, len(step.pixels), 3), MU)
            progress.add_spot_checks(step.pixels, checked, seconds)
        assert any(w.checked for w in progress.waves)
        stops.append(progress)
    assert all(p.stopped == "time_budget" for p in stops)
    assert stops[1].spp < stops[0].spp
    assert all(p.elapsed <= 6.0 * 1.25 for p in stops), [p.elapsed for p in stops]


def test_a_failed_spot_check_leaves_the_parts_estimate():
    """When the checks come back without pixels (their tracer failed), the estimate is the
    parts' own: here, not estimable."""
    width, height = 32, 24
    progress = ProgressiveFrame(width, height, Goal(max_spp=64))
    lit_pixel_wave(progress, width, height)
    assert isinstance(progress.next_part(), SpotCheck)
    progress.add_spot_checks(np.zeros((0, 2), int), np.zeros((PARTS, 0, 3)), 0.5)
    assert progress.waves[-1].checked == 0 and progress.error is None
    with pytest.raises(RuntimeError, match="spot check"):
        progress.add_spot_checks(np.zeros((0, 2), int), np.zeros((PARTS, 0, 3)), 0.5)


@pytest.fixture(scope="module")
def coordinator():
    connection = connect(num_cpus=2)
    coordinator = Coordinator(SceneGraph(studio()), tracers=2)
    yield coordinator
    coordinator.close()
    if connection.started:
        disconnect()


def test_through_the_coordinator(coordinator):
    """Waves through tracer actors: the image is the mean of samples [0, spp), which the
    library renders in one call (equal up to float32 rounding of the part means), and the
    reported error is the estimate from the parts and their spot checks (one pixel of this
    32x24 image per wave); a target at 1.5 times it stops the frame. Uniform waves (adaptive
    off: ``tests/cluster/test_adaptive.py`` checks adaptive ones)."""
    state = coordinator.graph.state
    camera = state.camera
    progress = ProgressiveFrame(camera.width, camera.height, Goal(max_spp=32), adaptive="off")
    while not progress.done:
        progressive_step(coordinator, progress, FrameRequest(0, camera, state.render))
    assert progress.stopped == "max_spp" and progress.spp == 32
    expected = render_image(compile_scene(state), settings=override(state.render, spp=32))[0]
    np.testing.assert_allclose(progress.image, expected, rtol=1e-5, atol=1e-6)
    assert progress.error > 0.0
    goal = Goal(target_error=progress.error * 1.5, max_spp=32)
    reached = render_progressive(coordinator, goal)  # the scene's adaptive sampling: auto
    assert reached.stopped == "target_error" and reached.mean_spp <= 32


def test_aovs_through_the_coordinator(coordinator):
    """Waves of parts with AOVs through tracer actors: the AOVs are the mean of samples [0, spp)
    that the library renders in one call, the ids bit for bit those of every pixel's sample 0
    (the first part's, not the last's)."""
    state = coordinator.graph.state
    camera, settings = state.camera, override(state.render, aovs=True)
    request = FrameRequest(0, camera, settings)
    progress = ProgressiveFrame(camera.width, camera.height, Goal(max_spp=16))
    while not progress.done:
        progressive_step(coordinator, progress, request)
    assert progress.spp == 16 and len(progress.waves) > 1
    compiled = compile_scene(state)

    def library(spp, sample_start=0):
        run = render_pixels(compiled, 0, camera.width * camera.height, camera,
                            override(settings, spp=spp), sample_start=sample_start)  # fmt: skip
        return run.aov.reshape(camera.height, camera.width, aov.CHANNELS)

    whole = library(16)
    means = [c for c in range(aov.CHANNELS) if c not in (aov.OBJECT_ID, aov.MATERIAL_ID)]
    np.testing.assert_allclose(progress.aov[..., means], whole[..., means], rtol=1e-5, atol=1e-5)
    assert np.array_equal(progress.aov[..., aov.IDS], whole[..., aov.IDS])
    assert not np.array_equal(progress.aov[..., aov.IDS], library(1, 15)[..., aov.IDS])


def test_spot_checks_through_the_coordinator(coordinator):
    """The coordinator shares the pixels out over its tracers (each reaching the frame's
    version: here after a commit); every pixel comes back with the parts the library renders
    for it, over its own sample range."""
    graph = coordinator.graph
    graph.commit(
        [{"op": "set_transform", "node": "box-a", "transform": {"translate": [0.4, 1, 0]}}]
    )
    pixels = np.array([[1, 2], [10, 20], [5, 5], [23, 31], [0, 0]])
    request = SpotCheck(pixels, np.array([0, 4, 0, 8, 2]), np.array([4, 4, 2, 2, 1]))
    got_pixels, got, work = coordinator.render_spot_checks(request)
    order = [pixels.tolist().index(p) for p in got_pixels.tolist()]
    assert sorted(order) == list(range(len(pixels)))
    expected, expected_work = render_spot_checks(
        compile_scene(graph.state), got_pixels, request.part_spp[order], request.part_start[order]
    )
    np.testing.assert_array_equal(got, expected)
    np.testing.assert_array_equal(work, expected_work)


def test_a_failed_share_drops_only_its_pixels(coordinator):
    """Two tracers, two pixels: the second tracer's pixel lies outside the frame, so its share
    fails; the first pixel still comes back, checked."""
    camera = coordinator.graph.state.camera
    request = SpotCheck(np.array([[3, 4], [camera.height, 0]]), np.array([0, 0]), np.array([2, 2]))
    got_pixels, got, work = coordinator.render_spot_checks(request)
    assert got_pixels.tolist() == [[3, 4]] and got.shape == (PARTS, 1, 3) and work.shape == (1,)

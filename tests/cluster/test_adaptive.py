"""Adaptive sampling in progressive frames (``cluster.adaptive``): waves give noisy pixels more
samples; sample ranges stay disjoint; the mean stays unbiased and the error estimate
calibrated with unequal counts; through tracers, the frame is the bits the library renders for
the same parts in one call, however the coordinator splits it."""

import math

import numpy as np
import pytest

from cluster import adaptive
from cluster.connect import connect, disconnect
from cluster.coordinator import Coordinator
from cluster.progressive import (
    Goal,
    ProgressiveFrame,
    SpotCheck,
    progressive_step,
    render_progressive,
)
from cluster.scene_graph import SceneGraph
from tests.worker.test_replica import studio
from tracer.accuracy.error_estimate import PARTS, REL_EPSILON
from tracer.accuracy.spot_check import render_spot_checks
from tracer.compiled.scene import compile_scene
from tracer.render import render_pixels
from tracer.request import FrameRequest
from tracer.scene.format import override

W, H = 24, 16
MU = 0.5


def noise_map(kind: str) -> np.ndarray:
    """Per-sample relative noise per pixel: ``half`` (the left half 8 times noisier than the
    right) or ``even``."""
    if kind == "even":
        return np.full((H, W), 0.25)
    sd = np.full((H, W), 0.125)
    sd[:, : W // 2] = 1.0
    return sd


def synthetic(part, sd: np.ndarray, seed: int) -> np.ndarray:
    """The part's image: pixel i the mean of its ``counts[i]`` (or ``spp``) Gaussian samples
    around MU, a reproducible draw of the part's sample range."""
    n = part.spp if part.counts is None else part.counts.reshape(H, W)
    rng = np.random.default_rng([seed, part.sample_start])
    return MU + (MU * sd / np.sqrt(n))[..., None] * rng.normal(size=(H, W, 3))


def drive(mode: str, kind: str, goal: Goal, seed: int = 0) -> tuple[ProgressiveFrame, list]:
    progress = ProgressiveFrame(W, H, goal, adaptive=mode)
    sd = noise_map(kind)
    parts = []
    while (part := progress.next_part()) is not None:
        parts.append(part)
        progress.add_part(synthetic(part, sd, seed), 0.01)
    return progress, parts


def true_rel_mse(image: np.ndarray) -> float:
    return float(np.mean((image - MU) ** 2 / (MU * MU + REL_EPSILON)))


def test_waves_give_noisy_pixels_more_samples():
    progress, parts = drive("on", "half", Goal(max_spp=512))
    start = 0
    for part in parts:  # the parts' sample ranges follow each other, as without adaptivity
        assert part.sample_start == start
        start += part.spp
        if part.counts is not None:
            assert part.counts.min() >= 1 and part.counts.max() <= part.spp
    waves = [parts[i : i + PARTS] for i in range(0, len(parts), PARTS)]
    for wave in waves:  # one count per pixel for every part of a wave
        first = wave[0].counts
        assert all(np.array_equal(p.counts, first) for p in wave) or first is None
    first_adaptive = next(i for i, w in enumerate(waves) if w[0].counts is not None)
    assert sum(w[0].spp for w in waves[:first_adaptive]) >= adaptive.START_PART_SPP
    spp = progress.pixel_spp
    assert progress.stopped == "max_spp" and 512 - PARTS < progress.mean_spp <= 512 + PARTS
    assert spp.max() <= progress.spp  # the range: the most a pixel took, wave by wave
    assert spp.sum() == sum(W * H * p.spp if p.counts is None else p.counts.sum() for p in parts)
    noisy, quiet = spp[:, 2 : W // 2 - 2].mean(), spp[:, W // 2 + 2 : -2].mean()
    # sqrt(r): 8 times the samples where the noise is 8 times higher, shared out around the mean.
    assert noisy > 4 * quiet and noisy > progress.mean_spp > quiet
    assert quiet >= adaptive.MIN_RATE * progress.mean_spp
    assert progress.mean_spp == pytest.approx(spp.mean())
    assert progress.waves[-1].adaptive and progress.summary()["mean_spp"] < 512


def test_auto_is_adaptive_only_where_it_wins():
    even, _ = drive("auto", "even", Goal(max_spp=256))
    assert not any(w.adaptive for w in even.waves) and (even.pixel_spp == 256).all()
    half, _ = drive("auto", "half", Goal(max_spp=256))
    assert any(w.adaptive for w in half.waves)
    _, parts = drive("off", "half", Goal(max_spp=256))
    assert all(p.counts is None for p in parts)


def test_the_mean_is_unbiased_and_the_estimate_calibrated_with_unequal_counts():
    """Over independent frames: the adaptive image's mean is MU (z-test on the error of the
    mean over pixels and frames), and the estimated relative MSE agrees with the true one
    (z-test on the frames' differences). Tolerances are 4 standard errors. (At a relative
    noise of the parts above about 0.3 the estimate reads high with or without adaptivity: its
    denominator is the parts' median squared.)"""
    frames = 40
    bias, estimated, true = [], [], []
    for seed in range(frames):
        progress, _ = drive("on", "half", Goal(max_spp=512), seed=seed)
        assert progress.waves[-1].adaptive
        image = progress.image.astype(np.float64)
        bias.append(np.mean(image - MU))
        estimated.append(progress.error**2)
        true.append(true_rel_mse(image))
    bias, estimated, true = map(np.asarray, (bias, estimated, true))
    assert abs(bias.mean()) < 4 * bias.std(ddof=1) / math.sqrt(frames)
    diff = estimated - true
    assert abs(diff.mean()) < 4 * diff.std(ddof=1) / math.sqrt(frames)
    assert estimated.mean() == pytest.approx(true.mean(), rel=0.15)


def test_a_time_budget_prices_the_adaptive_waves():
    """Seconds in proportion to the samples taken: the last wave fills what is left of the
    budget although adaptive waves take fewer samples than their range."""
    clock = [0.0]
    progress = ProgressiveFrame(W, H, Goal(time_budget=4.0), clock=lambda: clock[0], adaptive="on")
    sd = noise_map("half")
    while (part := progress.next_part()) is not None:
        n = part.spp if part.counts is None else part.counts.mean()
        seconds = 0.01 * n
        clock[0] += seconds
        progress.add_part(synthetic(part, sd, 0), seconds)
    assert progress.stopped == "time_budget" and progress.waves[-1].adaptive
    assert 0.75 * 4.0 < progress.elapsed <= 4.0


def test_bad_modes_are_refused():
    with pytest.raises(ValueError, match="adaptive"):
        ProgressiveFrame(W, H, Goal(), adaptive="sometimes")


@pytest.fixture(scope="module")
def coordinator():
    connection = connect(num_cpus=2)
    coordinator = Coordinator(SceneGraph(studio()), tracers=2)
    yield coordinator
    coordinator.close()
    if connection.started:
        disconnect()


def library_frame(state, goal: Goal, mode: str, seed: int | None = None) -> ProgressiveFrame:
    """The progressive frame rendered in this process, each part in one call (with another
    ``seed`` than the scene's if given)."""
    compiled = compile_scene(state)
    camera, settings = state.camera, state.render
    if seed is not None:
        settings = override(settings, seed=seed)
    progress = ProgressiveFrame(camera.width, camera.height, goal, adaptive=mode)
    while (step := progress.next_part()) is not None:
        if isinstance(step, SpotCheck):
            parts, work = render_spot_checks(
                compiled, step.pixels, step.part_spp, step.part_start, camera, settings
            )
            progress.add_spot_checks(step.pixels, parts, 0.0, work)
            continue
        run = render_pixels(
            compiled, 0, camera.width * camera.height, camera,
            override(settings, spp=step.spp), sample_start=step.sample_start, counts=step.counts,
        )  # fmt: skip
        rgb = run.rgb.reshape(camera.height, camera.width, 3)
        progress.add_part(rgb, 0.0, float(run.cost.sum()))
    return progress


def test_split_over_tracers_the_adaptive_frame_is_the_same_bits(coordinator):
    state = coordinator.graph.state
    camera = state.camera
    goal = Goal(max_spp=64)
    progress = ProgressiveFrame(camera.width, camera.height, goal, adaptive="on")
    request = FrameRequest(0, camera, state.render)
    while not progress.done:
        progressive_step(coordinator, progress, request)
    assert sum(w.adaptive for w in progress.waves) >= 2
    spp = progress.pixel_spp
    assert spp.min() < spp.max() <= progress.spp and progress.stopped == "max_spp"
    alone = library_frame(state, goal, "on")
    assert np.array_equal(alone.pixel_spp, spp)
    assert alone.image.tobytes() == progress.image.tobytes()
    assert alone.error == progress.error


def test_render_progressive_follows_the_scene(coordinator):
    """The scene's render.adaptive (auto by default) decides; the studio's lit floor and dark
    sky win, so auto samples adaptively there."""
    assert coordinator.graph.state.render.adaptive == "auto"
    progress = render_progressive(coordinator, Goal(max_spp=64))
    assert progress.summary()["adaptive"] == "auto" and progress.waves[-1].adaptive
    assert progress.summary()["adaptive_waves"] >= 1 and progress.mean_spp < 64


def test_an_adaptive_scene_frame_agrees_with_a_uniform_one(coordinator):
    """The studio at 64 spp, adaptive and uniform with another seed (independent): their
    difference, summed over the pixels, is within 4 standard errors of zero per channel (each
    pixel's variance from its frame's parts)."""
    state = coordinator.graph.state
    goal = Goal(max_spp=64)
    frames = [
        library_frame(state, goal, "on"),
        library_frame(state, goal, "off", seed=state.render.seed + 1),
    ]
    assert frames[0].pixel_spp.min() < 64 and (frames[1].pixel_spp == 64).all()
    diff = frames[0].image.astype(np.float64) - frames[1].image
    variance = 0.0
    for f in frames:
        parts = f.sums / f.part_counts[..., None]
        variance = variance + parts.var(axis=0, ddof=1) / PARTS
    z = diff.sum(axis=(0, 1)) / np.sqrt(variance.sum(axis=(0, 1)))
    assert (np.abs(z) < 4.0).all(), z

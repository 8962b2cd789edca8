"""A frame in bounded turns (``cluster.turns``): the runs a sizer cuts are whole lines or lie
inside one line, cover the frame once in order, and follow the measured rate; a frame and a
wave's spot checks rendered run by run give what one call gives. The coordinator here is a
stand-in that renders a pixel's index as its colour (the real tracers' regions are tested in
``tests/cluster/test_coordinator.py`` and through the service in ``tests/api/test_turns.py``)."""

import itertools
from dataclasses import dataclass, replace

import numpy as np
import pytest

from cluster.turns import FIRST_TURN_SAMPLES, GROWTH, TurnedFrame, TurnSizer, spot_checks_in_turns
from tracer.accuracy.error_estimate import PARTS
from tracer.accuracy.spot_check import SpotCheck
from tracer.errors import SceneError
from tracer.request import FrameRequest
from tracer.scene import format as fmt


def request_of(width: int, height: int, spp: int) -> FrameRequest:
    camera = fmt.Camera(width=width, height=height)
    return FrameRequest(0, camera, fmt.RenderSettings(spp=spp))


@dataclass
class RanFrame:
    rgb: np.ndarray
    cost: np.ndarray
    wall_seconds: float


class IndexCoordinator:
    """Renders each pixel as (index, index, index), taking ``seconds_per_sample`` per sample
    (reported, not slept)."""

    def __init__(self, seconds_per_sample: float = 1e-6) -> None:
        self.seconds_per_sample = seconds_per_sample
        self.regions: list[tuple[int, int] | None] = []
        self.checked: list[int] = []

    def render_frame(self, request: FrameRequest, graph) -> RanFrame:
        width, height = request.view()
        r0 = request.first_pixel
        self.regions.append(request.region)
        index = np.arange(r0, r0 + width * height, dtype=np.float32)
        rgb = np.repeat(index[:, None], 3, axis=1).reshape(height, width, 3)
        samples = width * height * request.spp
        seconds = samples * self.seconds_per_sample
        return RanFrame(rgb, np.full(height, width * request.spp), seconds)

    def render_spot_checks(self, checks: SpotCheck, request, graph):
        self.checked.append(len(checks.pixels))
        pixels = np.asarray(checks.pixels)
        parts = np.repeat(pixels[None, :, :1].astype(float), PARTS, axis=0)
        parts = np.concatenate([parts, parts, parts], axis=2)
        return pixels, parts, np.asarray(checks.part_spp) * PARTS


def run_all(generator):
    """Drive a turns generator to its end; (turns taken, its return value)."""
    turns = 1
    try:
        while True:
            next(generator)
            turns += 1
    except StopIteration as done:
        return turns, done.value


def test_a_region_is_whole_lines_or_a_run_inside_one_line():
    base = request_of(10, 4, 1)
    assert base.view() == (10, 4) and base.first_pixel == 0
    assert replace(base, region=(10, 30)).view() == (10, 2)
    assert replace(base, region=(13, 17)).view() == (4, 1)
    assert replace(base, region=(13, 17)).first_pixel == 13
    for bad in [(5, 15), (0, 41), (-1, 3), (7, 7)]:
        with pytest.raises(SceneError):
            replace(base, region=bad)


def test_the_first_turn_is_small_and_later_ones_follow_the_rate():
    sizer = TurnSizer(0.5)
    assert sizer.samples() == FIRST_TURN_SAMPLES
    sizer.observe(FIRST_TURN_SAMPLES, 0.001)  # fast: growth is capped
    assert sizer.samples() == int(GROWTH * FIRST_TURN_SAMPLES)
    sizer.observe(1000, 1.0)  # slow: half a second is 500 samples
    assert sizer.samples() == 500
    assert sizer.seconds_total == pytest.approx(1.001)


@pytest.mark.parametrize("spp", [1, 64, 4096])
def test_turns_cover_the_frame_once_in_order_within_lines(spp):
    """Whatever the cost of a line, every run is whole lines from a line's start or lies inside
    one line, and the runs tile the frame; the image is every pixel's own value."""
    width, height = 96, 40
    coordinator = IndexCoordinator(seconds_per_sample=2e-6)
    part = TurnedFrame(request_of(width, height, spp), TurnSizer(0.05))
    turns, _ = run_all(part.turns(coordinator, graph=None))
    regions = [r or (0, width * height) for r in coordinator.regions]
    assert turns == len(regions)
    assert regions[0][0] == 0 and regions[-1][1] == width * height
    assert all(a[1] == b[0] for a, b in itertools.pairwise(regions))
    for r0, r1 in regions:
        whole_lines = r0 % width == 0 and r1 % width == 0
        assert whole_lines or r0 // width == (r1 - 1) // width
    expected = np.arange(width * height, dtype=np.float32)
    assert np.array_equal(part.image[..., 1].ravel(), expected)
    assert part.samples_done == width * height * spp
    # Each turn after the first takes about the turn's seconds (or less, to a line's end).
    seconds = [(r1 - r0) * spp * 2e-6 for r0, r1 in regions[1:]]
    assert max(seconds, default=0.0) <= 0.05 * 1.001


def test_a_frame_that_fits_in_a_turn_is_one_whole_frame():
    coordinator = IndexCoordinator()
    part = TurnedFrame(request_of(32, 24, 4), TurnSizer(0.5))
    assert run_all(part.turns(coordinator, graph=None))[0] == 1
    assert coordinator.regions == [None]


def test_spot_checks_in_turns_return_what_one_call_returns():
    rng = np.random.default_rng(7)
    count = 300
    checks = SpotCheck(
        np.stack([rng.integers(0, 24, count), rng.integers(0, 32, count)], axis=1),
        rng.integers(0, 50, count),
        rng.integers(1, 200, count),
    )
    whole = IndexCoordinator().render_spot_checks(checks, None, None)
    coordinator = IndexCoordinator(seconds_per_sample=1e-6)
    sizer = TurnSizer(0.002)
    sizer.observe(1, 1e-6)  # the rate is known: a turn is about 2000 samples
    turns, (pixels, parts, work, seconds) = run_all(
        spot_checks_in_turns(coordinator, checks, None, None, sizer)
    )
    assert turns == len(coordinator.checked) > 5 and sum(coordinator.checked) == count
    assert np.array_equal(pixels, whole[0]) and np.array_equal(parts, whole[1])
    assert np.array_equal(work, whole[2]) and seconds >= 0.0

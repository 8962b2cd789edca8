"""A frame is a pure function of (scene, camera, settings, frame, sample range): however it is
split into line ranges, however many threads render it, the pixels and the per-line cost are
bit-identical; the seed, the frame index and the sample range are what change the noise."""

from itertools import pairwise

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tracer.render import render_image, render_lines
from tracer.scene.format import override

WIDTH, HEIGHT, SPP = 32, 24, 4


@pytest.fixture(scope="module")
def view(cornell):
    """(scene, camera, settings) for a small, non-square Cornell box render."""
    camera = override(cornell.camera, width=WIDTH, height=HEIGHT)
    return cornell, camera, override(cornell.render, spp=SPP)


@pytest.fixture(scope="module")
def whole(view):
    """The reference: the whole frame in one call on one thread."""
    scene, camera, render = view
    return render_lines(scene, 0, HEIGHT, camera, render, threads=1)


def render_split(view, cuts, threads=1, **kwargs):
    """Render the frame as the line ranges between ``cuts`` and stitch it back together."""
    scene, camera, render = view
    edges = [0, *cuts, HEIGHT]
    ranges = list(pairwise(edges))
    parts = [
        render_lines(scene, y0, y1, camera, render, threads=threads, **kwargs) for y0, y1 in ranges
    ]
    for part, (y0, y1) in zip(parts, ranges, strict=True):
        assert (part.y0, part.y1) == (y0, y1)
        assert part.rgb.shape == (y1 - y0, WIDTH, 3) and part.rgb.dtype == np.float32
        assert part.cost.shape == (y1 - y0,) and part.cost.dtype == np.int64
    return np.concatenate([p.rgb for p in parts]), np.concatenate([p.cost for p in parts])


def test_reference_render_is_sane(whole):
    """The reference is a finite, non-negative, non-constant image with positive cost; without
    this the equality tests below could pass on an all-black frame."""
    assert np.isfinite(whole.rgb).all() and (whole.rgb >= 0).all()
    assert whole.rgb.max() > 0.1 and whole.rgb.std() > 0.01
    assert (whole.cost > 0).all() and whole.spp == SPP


@pytest.mark.parametrize(
    "cuts",
    [[], [12], [1, 5, 6, 11, 17, 23], [3, 7, 10, 14, 17, 21]],
    ids=["1-way", "2-way", "7-way-uneven", "7-way"],
)
@pytest.mark.parametrize("threads", [1, 2])
def test_line_splits_are_bit_identical(view, whole, cuts, threads):
    """Splitting the frame into 1, 2 or 7 line ranges, on 1 or 2 threads, changes no bit of any
    pixel and no line's cost."""
    rgb, cost = render_split(view, cuts, threads=threads)
    assert np.array_equal(rgb, whole.rgb)
    assert np.array_equal(cost, whole.cost)


@settings(max_examples=8)
@given(
    cuts=st.sets(st.integers(1, HEIGHT - 1), max_size=HEIGHT - 1).map(sorted),
    threads=st.integers(1, 3),
)
def test_any_split_is_bit_identical(view, whole, cuts, threads):
    """Any partition of the lines, on any thread count, gives the same pixels and costs."""
    rgb, cost = render_split(view, cuts, threads=threads)
    assert np.array_equal(rgb, whole.rgb)
    assert np.array_equal(cost, whole.cost)


@pytest.mark.parametrize("lines_per_call", [1, 5, HEIGHT, None])
def test_render_image_matches_render_lines(view, whole, lines_per_call):
    """render_image, in chunks of any size, returns exactly the whole-frame render, and calls
    on_lines once per chunk, in order, covering every line."""
    scene, camera, render = view
    seen = []
    rgb, cost = render_image(
        scene,
        camera,
        render,
        lines_per_call=lines_per_call,
        threads=2,
        on_lines=lambda part: seen.append((part.y0, part.y1)),
    )
    assert np.array_equal(rgb, whole.rgb) and np.array_equal(cost, whole.cost)
    assert seen[0][0] == 0 and seen[-1][1] == HEIGHT
    assert all(a[1] == b[0] for a, b in pairwise(seen))


def test_same_seed_same_image(view, whole):
    """Rendering again with the same settings reproduces the image and the costs."""
    scene, camera, render = view
    again = render_lines(scene, 0, HEIGHT, camera, render, threads=2)
    assert np.array_equal(again.rgb, whole.rgb) and np.array_equal(again.cost, whole.cost)


def differing_fraction(a: np.ndarray, b: np.ndarray) -> float:
    """Fraction of the pixels lit in either image (the Cornell box's frame is black around the
    box's opening) whose values differ."""
    lit = (a > 0).any(axis=2) | (b > 0).any(axis=2)
    assert lit.mean() > 0.5
    return float((a != b).any(axis=2)[lit].mean())


@pytest.mark.parametrize(
    "change", [{"seed": 1}, {"seed": 2**63 - 1}, {"frame": 1}, {"frame": 1000}], ids=str
)
def test_seed_and_frame_change_the_noise(view, whole, change):
    """A different seed or frame index gives different noise in almost every lit pixel, with
    the same overall brightness."""
    scene, camera, render = view
    frame = change.get("frame", 0)
    if "seed" in change:
        render = override(render, seed=change["seed"])
    other = render_lines(scene, 0, HEIGHT, camera, render, frame=frame, threads=2)
    assert differing_fraction(other.rgb, whole.rgb) > 0.9
    # Same expectation: image means within a few standard errors of each other.
    a, b = whole.rgb.astype(np.float64), other.rgb.astype(np.float64)
    se = np.sqrt((a.var() + b.var()) / a[..., 0].size)
    assert abs(a.mean() - b.mean()) < 6 * se


def test_sample_ranges_split_the_estimate(view):
    """Samples [0, 4) and [4, 8) rendered separately average to the 8-sample render (equal up
    to float32 rounding of each mean), and are different estimates."""
    scene, camera, render = view
    first = render_lines(scene, 0, HEIGHT, camera, render, sample_start=0, threads=2)
    second = render_lines(scene, 0, HEIGHT, camera, render, sample_start=4, threads=2)
    both = render_lines(scene, 0, HEIGHT, camera, override(render, spp=8), threads=2)
    assert differing_fraction(first.rgb, second.rgb) > 0.9
    average = (first.rgb.astype(np.float64) + second.rgb.astype(np.float64)) / 2
    # Each mean is rounded to float32 once (relative error 2^-24); the average of two such
    # values is within 2^-23 relative of the exact mean, and so is the 8-sample render.
    np.testing.assert_allclose(both.rgb, average, rtol=2.0**-22, atol=0)
    assert np.array_equal(both.cost, first.cost + second.cost)


def test_sample_ranges_split_across_lines(view):
    """The sample-range split composes with the line split: lines [5, 9) from samples [4, 8)
    equal those lines of the whole frame rendered from samples [4, 8)."""
    scene, camera, render = view
    full = render_lines(scene, 0, HEIGHT, camera, render, sample_start=4, threads=1)
    part = render_lines(scene, 5, 9, camera, render, sample_start=4, threads=2)
    assert np.array_equal(part.rgb, full.rgb[5:9])
    assert np.array_equal(part.cost, full.cost[5:9])


@pytest.mark.parametrize(
    "y0, y1, kwargs",
    [
        (-1, 4, {}),
        (0, HEIGHT + 1, {}),
        (5, 5, {}),
        (6, 5, {}),
        (0, 1, {"frame": -1}),
        (0, 1, {"sample_start": -1}),
    ],
)
def test_render_lines_rejects_bad_ranges(view, y0, y1, kwargs):
    """Line ranges outside the image, empty ranges and negative frame or sample indices raise
    ValueError."""
    scene, camera, render = view
    with pytest.raises(ValueError):
        render_lines(scene, y0, y1, camera, render, **kwargs)

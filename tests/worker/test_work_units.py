"""Work units: every pixel of the frame in exactly one unit, in row-major order, units of
nearly equal width within a line, and enough units per tracer."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from worker.work_units import MAX_SPANS, MIN_SPAN_PIXELS, UNITS_PER_TRACER, WorkUnits


@st.composite
def frames(draw):
    width = draw(st.integers(1, 300))
    height = draw(st.integers(1, 40))
    spans = draw(st.integers(1, width))
    return WorkUnits(width, height, spans)


@given(frames())
def test_units_tile_the_frame_in_row_major_order(units):
    first = units.pixel(np.arange(units.count + 1))
    assert first[0] == 0 and first[-1] == units.width * units.height
    sizes = np.diff(first)
    assert sizes.min() >= 1  # no empty unit
    assert sizes.max() - sizes.min() <= 1  # spans of a line differ by at most a pixel
    lines = first[:: units.spans]
    assert np.array_equal(lines, np.arange(units.height + 1) * units.width)  # lines align


@given(frames(), st.data())
def test_per_unit_and_per_line_sums(units, data):
    u0 = data.draw(st.integers(0, units.count - 1))
    u1 = data.draw(st.integers(u0 + 1, units.count))
    p0, p1 = units.pixels(u0, u1)
    values = np.arange(p0, p1, dtype=np.int64) % 7 + 1
    per_unit = units.per_unit(u0, u1, values)
    assert per_unit.shape == (u1 - u0,) and per_unit.sum() == values.sum()
    assert np.array_equal(
        per_unit, [values[a - p0 : b - p0].sum() for a, b in _runs(units, u0, u1)]
    )
    everything = units.per_unit(0, units.count, np.ones(units.width * units.height, np.int64))
    assert np.array_equal(units.per_line(everything), np.full(units.height, units.width))


def _runs(units, u0, u1):
    return [(units.pixel(u), units.pixel(u + 1)) for u in range(u0, u1)]


@pytest.mark.parametrize("tracers", [1, 2, 3, 8, 32, 128, 1000])
@pytest.mark.parametrize("size", [(640, 480), (128, 96), (64, 48), (12, 5), (1, 1)])
def test_for_tracers_gives_each_tracer_enough_units(tracers, size):
    width, height = size
    units = WorkUnits.for_tracers(width, height, tracers)
    spans = units.spans
    assert spans & (spans - 1) == 0 and spans <= MAX_SPANS  # a power of two
    if tracers == 1:
        assert spans == 1
        return
    widest = width // MIN_SPAN_PIXELS
    assert spans == 1 or width // spans >= MIN_SPAN_PIXELS
    if units.count < UNITS_PER_TRACER * tracers:  # only when no finer spans are allowed
        assert 2 * spans > min(MAX_SPANS, max(1, widest))
    elif spans > 1:  # and no more spans than needed
        assert height * spans // 2 < UNITS_PER_TRACER * tracers


def test_the_spans_of_the_issue_frames():
    """640x480: whole lines for 2 tracers, 10-pixel spans for 128."""
    assert [WorkUnits.for_tracers(640, 480, t).spans for t in (2, 3, 8, 32, 128)] == [
        1,
        2,
        4,
        16,
        64,
    ]


def test_bad_ranges_and_frames_are_refused():
    units = WorkUnits(10, 3, 2)
    for u0, u1 in [(0, 0), (-1, 2), (2, 1), (0, 7)]:
        with pytest.raises(ValueError, match="unit range"):
            units.pixels(u0, u1)
    with pytest.raises(ValueError, match="spans"):
        WorkUnits(4, 4, 5)
    with pytest.raises(ValueError, match="pixels"):
        WorkUnits(0, 4)

"""A frame's work units: the pieces the coordinator balances, hands out and assembles.

A unit is a run of pixels in row-major order: each of the frame's ``height`` lines is cut into
``spans`` spans of (nearly) equal width, and unit ``u`` is span ``u % spans`` of line
``u // spans``; ``spans = 1`` makes every unit a whole line. A range of units ``[u0, u1)`` is
one pixel run ``[pixel(u0), pixel(u1))``, which the tracer renders with
:func:`tracer.render.render_pixels` (every pixel gets the same bits in any split).

Why spans: a balancer cannot place a cut, nor the dynamic tail cut a chunk, finer than a
unit. With 480 lines and 128 tracers a tracer's share is under four lines, and one dear line
more or less is a large part of its frame (``docs/balancing.md``). :meth:`WorkUnits.for_tracers`
gives every frame at least ``UNITS_PER_TRACER`` units per tracer where spans of at least
``MIN_SPAN_PIXELS``, at most ``MAX_SPANS`` a line, allow it: whole lines for two tracers on
480 lines, 64 spans of 10 pixels for 128 tracers on 640x480.
"""

from dataclasses import dataclass

import numpy as np

UNITS_PER_TRACER = 240
"""Least units per tracer of a frame (as many as there are spans): a unit is then at most
about 0.4% of an equal share, finer than the few percent a tracer's speed varies."""
MAX_SPANS = 64
"""Most spans per line (a power of two: traces recorded at 64 spans sum to any fewer)."""
MIN_SPAN_PIXELS = 8
"""Least pixels in a span (a span's fixed costs stay small against its rays)."""


@dataclass(frozen=True)
class WorkUnits:
    """The units of a ``width`` x ``height`` frame, ``spans`` per line."""

    width: int
    height: int
    spans: int = 1

    def __post_init__(self) -> None:
        if self.width < 1 or self.height < 1:
            raise ValueError(f"a frame needs pixels, not {self.width}x{self.height}")
        if not 1 <= self.spans <= self.width:
            raise ValueError(f"spans must be in [1, {self.width}] (the width), not {self.spans}")

    @classmethod
    def for_tracers(cls, width: int, height: int, tracers: int) -> "WorkUnits":
        """The fewest spans (a power of two, at most ``MAX_SPANS`` and no narrower than
        ``MIN_SPAN_PIXELS``) giving at least ``UNITS_PER_TRACER`` units per tracer; whole
        lines for a single tracer."""
        if tracers <= 1:
            return cls(width, height)
        widest = max(1, min(MAX_SPANS, width // MIN_SPAN_PIXELS))
        spans = 1
        while height * spans < UNITS_PER_TRACER * tracers and 2 * spans <= widest:
            spans *= 2
        return cls(width, height, spans)

    @property
    def count(self) -> int:
        """Units in the frame."""
        return self.height * self.spans

    def pixel(self, unit: int | np.ndarray) -> int | np.ndarray:
        """First pixel (row-major index) of ``unit`` (an int or an integer array); ``pixel(count)``
        is the number of pixels."""
        line, span = np.divmod(unit, self.spans)
        first = line * self.width + span * self.width // self.spans
        return int(first) if np.ndim(first) == 0 else first

    def pixels(self, u0: int, u1: int) -> tuple[int, int]:
        """The pixel run ``[p0, p1)`` of units ``[u0, u1)``."""
        self.check(u0, u1)
        return self.pixel(u0), self.pixel(u1)

    def sizes(self, u0: int, u1: int) -> np.ndarray:
        """Pixels in each of units ``[u0, u1)``."""
        return np.diff(self.pixel(np.arange(u0, u1 + 1)))

    def per_unit(self, u0: int, u1: int, per_pixel: np.ndarray) -> np.ndarray:
        """Sums of ``per_pixel`` (the values of the run ``pixels(u0, u1)``) over each unit."""
        starts = self.pixel(np.arange(u0, u1)) - self.pixel(u0)
        if starts.size == 0:
            return np.zeros(0, np.asarray(per_pixel).dtype)
        return np.add.reduceat(np.asarray(per_pixel), starts)

    def per_line(self, per_unit: np.ndarray) -> np.ndarray:
        """Sums of a value of every unit of the frame over each line."""
        return np.asarray(per_unit).reshape(self.height, self.spans).sum(axis=1)

    def lines(self, u0: int, u1: int) -> float:
        """How many lines units ``[u0, u1)`` amount to."""
        return (u1 - u0) / self.spans

    def check(self, u0: int, u1: int) -> None:
        """ValueError unless ``[u0, u1)`` is a non-empty range of the frame's units."""
        if not 0 <= u0 < u1 <= self.count:
            raise ValueError(f"unit range [{u0}, {u1}) is not inside [0, {self.count})")

"""Frame assembly: work-unit ranges from tracers into one float32 image (Brigade, Bikker 7.3.2).

An :class:`Assembler` belongs to one frame scheduled at one scene version, cut into work
units (:mod:`worker.work_units`: whole lines, or spans of them). The coordinator registers
every range it hands out (the balancer's split, pieces of a lost range, speculative
duplicates); a result is accepted only if its frame, version and exact range were assigned, so
a late answer to an older frame or version can never land in this one. The first result to
cover a unit writes it; later deliveries of the same units (a retry, the losing copy of a
duplicate) are accepted and change nothing: tracers are deterministic per pixel, so they carry
the same values anyway.
"""

import numpy as np

from tracer.integrators.aov import CHANNELS
from worker.work_units import WorkUnits


class Assembler:
    """The image and per-unit cost of one frame, filled range by range."""

    def __init__(self, frame: int, version: int, units: WorkUnits, aovs: bool = False):
        self.frame = frame
        self.version = version
        self.units = units
        self.width, self.height = units.width, units.height
        self.rgb = np.zeros((self.height, self.width, 3), np.float32)
        self._pixels = self.rgb.reshape(-1, 3)  # a view: row-major pixel runs
        self.aov = np.zeros((self.height, self.width, CHANNELS), np.float32) if aovs else None
        """float32 (H, W, ``aov.CHANNELS``) when the frame renders AOVs
        (``tracer.integrators.aov``): every result must then carry them."""
        self.cost = np.zeros(units.count, np.int64)
        """Work per unit."""
        self.rays = np.zeros(units.count, np.int64)
        """Rays traced per unit (zero for units of results that did not count them)."""
        self.done = np.zeros(units.count, bool)
        self._assigned: set[tuple[int, int]] = set()
        self.rejected = 0
        """Results refused: wrong frame, version, range or shape."""

    def assign(self, u0: int, u1: int) -> None:
        """Expect a result for exactly units [u0, u1)."""
        self.units.check(u0, u1)
        self._assigned.add((u0, u1))

    def accepts(self, frame: int, version: int, u0: int, u1: int) -> bool:
        return frame == self.frame and version == self.version and (u0, u1) in self._assigned

    def accept(self, result) -> int:
        """Write a tracer's result (``frame``, ``version``, ``u0``, ``u1``, ``spans``, ``rgb``
        (pixels, 3), ``cost`` per unit, optionally ``rays`` per unit, and ``aov`` (pixels,
        ``aov.CHANNELS``) when the frame renders AOVs); returns the number of units it
        completed, or -1 if it was refused."""
        u0, u1 = result.u0, result.u1
        rgb = np.asarray(result.rgb)
        cost = np.asarray(result.cost)
        if not self.accepts(result.frame, result.version, u0, u1) or (
            getattr(result, "spans", 1) != self.units.spans
        ):
            self.rejected += 1
            return -1
        p0, p1 = self.units.pixels(u0, u1)
        if rgb.shape != (p1 - p0, 3) or cost.shape != (u1 - u0,):
            self.rejected += 1
            return -1
        aov = getattr(result, "aov", None)
        if self.aov is not None and np.shape(aov) != (p1 - p0, CHANNELS):
            self.rejected += 1
            return -1
        new = ~self.done[u0:u1]
        count = int(new.sum())
        if count:
            pixels = np.repeat(new, self.units.sizes(u0, u1))
            self._pixels[p0:p1][pixels] = rgb[pixels]
            if self.aov is not None:
                self.aov.reshape(-1, CHANNELS)[p0:p1][pixels] = np.asarray(aov)[pixels]
            self.cost[u0:u1][new] = cost[new]
            rays = getattr(result, "rays", None)
            if rays is not None and np.shape(rays) == cost.shape:
                self.rays[u0:u1][new] = np.asarray(rays)[new]
            self.done[u0:u1] = True
        return count

    @property
    def complete(self) -> bool:
        return bool(self.done.all())

    def missing(self, u0: int = 0, u1: int | None = None) -> list[tuple[int, int]]:
        """Runs of units in [u0, u1) that no accepted result has covered yet."""
        u1 = self.units.count if u1 is None else u1
        return runs(~self.done[u0:u1], offset=u0)

    def line_cost(self) -> np.ndarray:
        """int64 (H,): work per line."""
        return self.units.per_line(self.cost)

    def line_rays(self) -> np.ndarray:
        """int64 (H,): rays traced per line."""
        return self.units.per_line(self.rays)


def runs(mask: np.ndarray, offset: int = 0) -> list[tuple[int, int]]:
    """The maximal runs ``[a, b)`` where ``mask`` is true, shifted by ``offset``."""
    padded = np.concatenate(([False], np.asarray(mask, bool), [False]))
    edges = np.flatnonzero(padded[1:] != padded[:-1])
    return [
        (int(a) + offset, int(b) + offset) for a, b in zip(edges[::2], edges[1::2], strict=True)
    ]

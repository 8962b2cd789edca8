"""Frame assembly: line ranges from tracers into one float32 image (Brigade, Bikker 7.3.2).

An :class:`Assembler` belongs to one frame scheduled at one scene version. The coordinator
registers every range it hands out (the balancer's split, pieces of a lost range, speculative
duplicates); a result is accepted only if its frame, version and exact range were assigned, so
a late answer to an older frame or version can never land in this one. The first result to
cover a line writes it; later deliveries of the same lines (a retry, the losing copy of a
duplicate) are accepted and change nothing: tracers are deterministic per pixel, so they carry
the same values anyway.
"""

import numpy as np


class Assembler:
    """The image and per-line cost of one frame, filled range by range."""

    def __init__(self, frame: int, version: int, width: int, height: int):
        self.frame = frame
        self.version = version
        self.width = width
        self.height = height
        self.rgb = np.zeros((height, width, 3), np.float32)
        self.cost = np.zeros(height, np.int64)
        self.rays = np.zeros(height, np.int64)
        """Rays traced per line (zero for lines of results that did not count them)."""
        self.done = np.zeros(height, bool)
        self._assigned: set[tuple[int, int]] = set()
        self.rejected = 0
        """Results refused: wrong frame, version, range or shape."""

    def assign(self, y0: int, y1: int) -> None:
        """Expect a result for exactly lines [y0, y1)."""
        if not 0 <= y0 < y1 <= self.height:
            raise ValueError(f"range [{y0}, {y1}) is not inside [0, {self.height})")
        self._assigned.add((y0, y1))

    def accepts(self, frame: int, version: int, y0: int, y1: int) -> bool:
        return frame == self.frame and version == self.version and (y0, y1) in self._assigned

    def accept(self, result) -> int:
        """Write a tracer's result (``frame``, ``version``, ``y0``, ``y1``, ``rgb``, ``cost``
        and optionally ``rays`` attributes); returns the number of lines it completed, or -1 if
        it was refused."""
        y0, y1 = result.y0, result.y1
        rgb = np.asarray(result.rgb)
        cost = np.asarray(result.cost)
        if not self.accepts(result.frame, result.version, y0, y1) or (
            rgb.shape != (y1 - y0, self.width, 3) or cost.shape != (y1 - y0,)
        ):
            self.rejected += 1
            return -1
        new = ~self.done[y0:y1]
        count = int(new.sum())
        if count:
            self.rgb[y0:y1][new] = rgb[new]
            self.cost[y0:y1][new] = cost[new]
            rays = getattr(result, "rays", None)
            if rays is not None and np.shape(rays) == cost.shape:
                self.rays[y0:y1][new] = np.asarray(rays)[new]
            self.done[y0:y1] = True
        return count

    @property
    def complete(self) -> bool:
        return bool(self.done.all())

    def missing(self, y0: int = 0, y1: int | None = None) -> list[tuple[int, int]]:
        """Runs of lines in [y0, y1) that no accepted result has covered yet."""
        y1 = self.height if y1 is None else y1
        return runs(~self.done[y0:y1], offset=y0)


def runs(mask: np.ndarray, offset: int = 0) -> list[tuple[int, int]]:
    """The maximal runs ``[a, b)`` where ``mask`` is true, shifted by ``offset``."""
    padded = np.concatenate(([False], np.asarray(mask, bool), [False]))
    edges = np.flatnonzero(padded[1:] != padded[:-1])
    return [
        (int(a) + offset, int(b) + offset) for a, b in zip(edges[::2], edges[1::2], strict=True)
    ]

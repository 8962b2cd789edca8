"""The shared pools a frame's dynamic tail may go to: a small file in shared memory when every
tracer of the frame runs on the coordinator's Ray node (:mod:`worker.line_pool`), else a table
in one pool actor on that node (:mod:`worker.remote_pool`)."""

import itertools
import logging

import ray
from ray.exceptions import RayError

from cluster.fleet import TracerSlot, first_line
from worker.line_pool import LinePool
from worker.line_pool import supported as line_pool_supported
from worker.line_pool import sweep as line_pool_sweep
from worker.remote_pool import REMOTE_CLAIM_SECONDS, RemotePool, remote_tables

log = logging.getLogger("tilerender.cluster")


class SharedPools:
    """The open pools of a coordinator on Ray node ``node``, and the actor holding remote
    ones (made when first needed, again after it is lost)."""

    def __init__(self, node: str, allowed: bool) -> None:
        self.node = node
        self.open: set[LinePool | RemotePool] = set()
        self.tables = None
        self._keys = itertools.count()
        if allowed and line_pool_supported():
            line_pool_sweep()

    def shares_file(self, slots: list[TracerSlot]) -> bool:
        """Whether every one of ``slots`` can open a pool file made here (on this node)."""
        return line_pool_supported() and all(
            s.node == self.node and not s.pool_blind for s in slots
        )

    @staticmethod
    def claim_seconds(local: bool) -> float:
        """What one claim costs a tracer."""
        return 0.0 if local else REMOTE_CLAIM_SECONDS

    def create(self, chunks: list[tuple[int, int]], local: bool) -> LinePool | RemotePool:
        """A pool of ``chunks``: a file (``local``), else a table in the pool actor."""
        if local:
            pool = LinePool.create(chunks)
        else:
            if self.tables is None:
                self.tables = remote_tables(self.node)
                ray.get(self.tables.rows.remote(-1))  # up before tracers claim from it
            pool = RemotePool.create(self.tables, chunks, next(self._keys))
        self.open.add(pool)
        return pool

    def remove(self, pool: LinePool | RemotePool | None) -> None:
        if pool is not None:
            pool.unlink()
            self.open.discard(pool)

    def lose(self, error: Exception) -> None:
        """The pool actor is gone (its node's memory monitor, say): the next pooled frame
        starts a new one."""
        log.warning("the pool actor is lost: %s", first_line(error))
        self.tables = None

    def close(self) -> None:
        """Remove every pool and stop the pool actor."""
        for pool in self.open:
            try:
                pool.unlink()
            except RayError:  # pragma: no cover - Ray is already down
                pass
        self.open.clear()
        if self.tables is not None:
            try:
                ray.kill(self.tables)
            except RayError:  # pragma: no cover - already gone
                pass
            self.tables = None

"""A frame's dynamic tail shared by tracers on several machines: chunks held by a Ray actor.

The same claim-as-you-go scheme as :mod:`worker.line_pool`, for frames whose tracers do not
all share the coordinator's machine: the chunk table lives in a small actor
(:class:`PoolTables`, on the coordinator's node, no CPU reserved), and a claim is one actor
call instead of a file lock. Ray runs an actor's calls one at a time, so claims are atomic.
A call takes up to about a millisecond (against microseconds for the file), so after its
first claim a tracer asks for its next chunk *before* it renders the current one
(:meth:`RemotePool.claims`), and chunks are at least twice ``REMOTE_CLAIM_SECONDS`` of the
slowest tracer's time, so the answer is usually back by the time it needs it (a faster
tracer may wait on the smallest chunks: in the simulator a floor in the fastest tracer's
time cost more than the waits it saved). Keys are numbers the
coordinator counts up: a claim for a key above the newest table opened arrives before its
``open`` (Ray orders calls per caller only) and is told to ask again; one at or below it was
closed. In the simulator (``bench/balance_sim.py --calls --remote-pool``, which models the
round trips, claims sent ahead and answered in arrival order, but no queue at the actor)
this idles 1.3 / 2.7 / 4.1% with 8 / 32 / 128 tracers on separate machines, where the
static split idles 5.1 / 8.1 / 11.9%.

:class:`RemotePool` is the handle both sides use: the coordinator creates it (``create``),
passes it to every tracer's render call, and asks it which chunks an owner claimed when a
tracer is lost or stalls; a tracer claims chunks from it until none is left. It has the
methods of :class:`worker.line_pool.LinePool` that those users need.
"""

import time
from collections.abc import Iterator, Sequence

from tracer.errors import TilerenderError

WAIT = "wait"
"""What a claim on a table not opened yet answers."""
WAIT_SECONDS = 0.0005
WAIT_LIMIT = 30.0
"""Seconds a claimer waits for a table to be opened before it gives the pool up."""
REMOTE_CLAIM_SECONDS = 0.0005
"""A claim's round trip to the pool actor within a cluster (up to about a millisecond under
load); chunks are at least twice that, 1 ms."""


class PoolTables:
    """Chunk tables by key: ``[u0, u1, owner]`` rows (owner -1 until claimed) and the next
    row to hand out. Plain, so the tests drive it without Ray; :func:`remote_tables` makes
    the actor."""

    def __init__(self) -> None:
        self._tables: dict[int, tuple[list[list[int]], list[int]]] = {}
        self._newest = -1

    def open(self, key: int, chunks: Sequence[tuple[int, int]]) -> int:
        """A new table ``key`` (above every key opened before) holding ``chunks`` in hand-out
        order; returns their number."""
        check_chunks(chunks)
        self._tables[key] = ([[int(u0), int(u1), -1] for u0, u1 in chunks], [0])
        self._newest = max(self._newest, key)
        return len(chunks)

    def claim(self, key: int, owner: int) -> tuple[int, int] | str | None:
        """The next chunk of ``key`` for ``owner``; None when all are taken or the table is
        closed; ``WAIT`` when it is not open yet (the coordinator's ``open`` and a tracer's
        first claim come from different processes, so Ray does not order them)."""
        table = self._tables.get(key)
        if table is None:
            return WAIT if key > self._newest else None
        rows, cursor = table
        if cursor[0] >= len(rows):
            return None
        row = rows[cursor[0]]
        cursor[0] += 1
        row[2] = owner
        return row[0], row[1]

    def rows(self, key: int) -> list[tuple[int, int, int]]:
        """Every chunk of ``key`` as (u0, u1, owner); empty when closed."""
        table = self._tables.get(key)
        return [] if table is None else [tuple(row) for row in table[0]]

    def close(self, key: int) -> None:
        """Forget ``key``: later claims find nothing."""
        self._tables.pop(key, None)


def check_chunks(chunks: Sequence[tuple[int, int]]) -> None:
    """ValueError for an empty or negative chunk."""
    for u0, u1 in chunks:
        if not 0 <= u0 < u1:
            raise ValueError(f"chunk [{u0}, {u1}) is empty or negative")


class PoolLost(TilerenderError, RuntimeError):
    """The pool actor is gone (its node, or Ray's memory monitor, took it)."""


_REMOTE = None


def remote_tables(node_id: str | None = None):
    """A :class:`PoolTables` actor reserving no CPU, on ``node_id`` when given (the
    coordinator's own node: it lives as long as the coordinator; Ray's soft affinity would
    put it on any node)."""
    import ray
    from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

    global _REMOTE
    if _REMOTE is None:
        _REMOTE = ray.remote(PoolTables)
    options = {"num_cpus": 0, "max_restarts": 0}
    if node_id is not None:
        options["scheduling_strategy"] = NodeAffinitySchedulingStrategy(node_id, soft=False)
    return _REMOTE.options(**options).remote()


class RemotePool:
    """One frame's chunks in a :class:`PoolTables` actor (see the module docstring). Calls
    that find the actor gone raise :class:`PoolLost`."""

    def __init__(self, tables, key: int) -> None:
        self.tables = tables
        self.key = key

    @property
    def path(self) -> str:
        """The table's key (the file pool's path plays this part in log lines)."""
        return f"pool table {self.key}"

    @property
    def ticket(self) -> "RemotePool":
        """What a tracer's render call needs to claim from this pool: the pool itself (an
        actor handle and a key)."""
        return self

    @classmethod
    def create(cls, tables, chunks: Sequence[tuple[int, int]], key: int) -> "RemotePool":
        """A new table ``key`` (above every key used with ``tables`` before) in the
        ``tables`` actor, sent without waiting: a claim that arrives first is told to wait."""
        check_chunks(chunks)
        pool = cls(tables, key)
        tables.open.remote(key, [(int(a), int(b)) for a, b in chunks])
        return pool

    def _get(self, ref):
        import ray
        from ray.exceptions import RayActorError

        try:
            return ray.get(ref)
        except RayActorError as error:
            raise PoolLost(
                str(error).splitlines()[0] if str(error) else "pool actor lost"
            ) from None

    def _answer(self, ref, owner: int) -> tuple[int, int] | None:
        """The chunk a claim answered, claiming again while the table is not open yet."""
        deadline = time.monotonic() + WAIT_LIMIT
        while (chunk := self._get(ref)) == WAIT:
            if time.monotonic() > deadline:
                raise PoolLost(f"table {self.key} was not opened within {WAIT_LIMIT:g} s")
            time.sleep(WAIT_SECONDS)
            ref = self.tables.claim.remote(self.key, owner)
        return None if chunk is None else (int(chunk[0]), int(chunk[1]))

    def claim(self, owner: int) -> tuple[int, int] | None:
        return self._answer(self.tables.claim.remote(self.key, owner), owner)

    def claims(self, owner: int) -> Iterator[tuple[int, int]]:
        """Chunks for ``owner`` until none is left, each after the first claimed while the
        one before it is being rendered (so a tracer holds at most one chunk it has not
        started)."""
        ahead = self.tables.claim.remote(self.key, owner)
        while (chunk := self._answer(ahead, owner)) is not None:
            ahead = self.tables.claim.remote(self.key, owner)
            yield chunk

    def _rows(self) -> list[tuple[int, int, int]]:
        return self._get(self.tables.rows.remote(self.key))  # after open: same caller, in order

    def claimed(self, owner: int | None = None) -> list[tuple[int, int]]:
        """Chunks claimed so far (by ``owner`` only, when given)."""
        return [
            (u0, u1) for u0, u1, who in self._rows() if who >= 0 and (owner is None or who == owner)
        ]

    def unclaimed(self) -> list[tuple[int, int]]:
        """Chunks nobody has claimed yet."""
        return [(u0, u1) for u0, u1, who in self._rows() if who < 0]

    def unlink(self) -> None:
        """Close the table (without waiting): tracers that claim later find nothing."""
        self.tables.close.remote(self.key)

    def __enter__(self) -> "RemotePool":
        return self

    def __exit__(self, *exc) -> None:
        pass

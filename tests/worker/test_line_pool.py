"""The shared line pool: chunks handed out once each, in order, to whichever process claims
first, with the claimant recorded; a pool that is gone reads as none."""

import multiprocessing
import os

import pytest

from worker import line_pool
from worker.line_pool import LinePool, supported

pytestmark = pytest.mark.skipif(not supported(), reason="line pools need POSIX file locks")

CHUNKS = [(10, 14), (2, 3), (14, 20), (0, 2), (3, 10)]


def test_chunks_come_out_in_order_once_each_with_their_owner():
    pool = LinePool.create(CHUNKS)
    try:
        assert len(pool) == 5 and pool.unclaimed() == CHUNKS and pool.claimed() == []
        assert pool.claim(7) == (10, 14)
        assert pool.claim(3) == (2, 3)
        assert pool.claim(7) == (14, 20)
        assert pool.claimed(7) == [(10, 14), (14, 20)] and pool.claimed(3) == [(2, 3)]
        assert pool.unclaimed() == [(0, 2), (3, 10)]
        other = LinePool.open(pool.path)  # a second mapping sees the same table
        with other:
            assert other.claim(1) == (0, 2)
        assert pool.claim(3) == (3, 10)
        assert pool.claim(3) is None and pool.claim(7) is None
        assert pool.claimed() == CHUNKS and pool.unclaimed() == []
        assert pool.chunk(3) == (0, 2, 1)
    finally:
        pool.unlink()
    assert LinePool.open(pool.path) is None


def test_an_empty_pool_has_nothing_to_claim_and_bad_chunks_are_refused():
    pool = LinePool.create([])
    try:
        assert len(pool) == 0 and pool.claim(0) is None
    finally:
        pool.unlink()
    for bad in ([(3, 3)], [(-1, 2)], [(5, 4)]):
        with pytest.raises(ValueError, match="empty or negative"):
            LinePool.create(bad)


def _claim_all(path: str, owner: int, out) -> None:
    pool = LinePool.open(path)
    taken = []
    with pool:
        while (chunk := pool.claim(owner)) is not None:
            taken.append(chunk)
    out.put((owner, taken))


def test_processes_racing_for_chunks_get_each_exactly_once():
    """Four processes claim 2,000 one-line chunks as fast as they can: every chunk is taken by
    exactly one of them, and the table names that one as its owner."""
    chunks = [(y, y + 1) for y in range(2000)]
    pool = LinePool.create(chunks)
    try:
        context = multiprocessing.get_context("spawn")
        out = context.Queue()
        workers = [context.Process(target=_claim_all, args=(pool.path, k, out)) for k in range(4)]
        for worker in workers:
            worker.start()
        results = dict(out.get(timeout=120) for _ in workers)
        for worker in workers:
            worker.join(timeout=60)
        taken = sorted(chunk for got in results.values() for chunk in got)
        assert taken == chunks
        for owner, got in results.items():
            assert pool.claimed(owner) == got
    finally:
        pool.unlink()


def test_sweep_removes_the_pools_of_processes_that_are_gone():
    """A pool named after a process that no longer exists (its coordinator died mid-frame) is
    removed by the next sweep; a live process's pool stays."""
    mine = LinePool.create([(0, 1)])
    context = multiprocessing.get_context("spawn")
    gone = context.Process(target=int)
    gone.start()
    gone.join()
    orphan = line_pool._directory() / f"{line_pool.PREFIX}-{gone.pid}-deadbeef"
    orphan.write_bytes(b"")
    try:
        assert line_pool.sweep() >= 1
        assert not orphan.exists() and os.path.exists(mine.path)
    finally:
        mine.unlink()
        orphan.unlink(missing_ok=True)

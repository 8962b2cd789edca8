"""A frame's dynamic tail shared by the tracers of one machine: chunks in shared memory.

A chunk is a range ``[u0, u1)`` of the frame's work units (:mod:`worker.work_units`: whole
lines, or spans of them). The coordinator writes the tail's chunks (in the order they are to
be handed out) into a small file in ``/dev/shm`` (the temp directory where there is none);
each tracer whose render call names the pool renders its own range, then claims chunks one at a time
until none is left, and returns them with its range. A claim is a few microseconds (an exclusive
``flock`` around a counter in the mapped file) instead of the millisecond a Ray call costs, so
chunks can be small and no tracer waits for the coordinator within a frame. Every claim records its
owner, so the coordinator can tell which units a lost or stalled tracer held.

Layout (int64): ``[next, count, (u0, u1, owner) x count]``; ``owner`` is -1 until claimed.
Only processes on the coordinator's machine can open the file (a tracer that cannot says so,
and the coordinator hands the chunks out itself). The file is named after the creating
process, so pools left behind by a process that died are removed by the next
:func:`sweep`.
"""

import mmap
import os
import tempfile
import uuid
from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np

try:
    import fcntl
except ImportError:  # pragma: no cover - not POSIX
    fcntl = None

HEADER = 2
FIELDS = 3
PREFIX = "tilerender-pool"


def supported() -> bool:
    """Whether this platform has the file locks the pool needs (POSIX)."""
    return fcntl is not None


def _directory() -> Path:
    shm = Path("/dev/shm")
    return shm if shm.is_dir() and os.access(shm, os.W_OK) else Path(tempfile.gettempdir())


def sweep() -> int:
    """Remove the pools of processes that no longer exist (a coordinator that died mid-frame);
    returns how many."""
    removed = 0
    for path in _directory().glob(f"{PREFIX}-*"):
        try:
            pid = int(path.name.split("-")[2])
            os.kill(pid, 0)
        except (IndexError, ValueError, ProcessLookupError):
            path.unlink(missing_ok=True)
            removed += 1
        except PermissionError:  # alive, another user's
            pass
    return removed


class LinePool:
    """Chunks of work units claimed by several processes; see the module docstring. After
    :meth:`close` the pool reads as it was then and has nothing left to claim."""

    def __init__(self, path: str, fd: int, buffer: mmap.mmap) -> None:
        self.path = path
        self._fd = fd
        self._buffer = buffer
        self._table = np.frombuffer(buffer, np.int64)

    @classmethod
    def create(cls, chunks: Sequence[tuple[int, int]]) -> "LinePool":
        """A new pool holding ``chunks`` in hand-out order."""
        if not supported():  # pragma: no cover - not POSIX
            raise OSError("line pools need POSIX file locks")
        table = np.full(HEADER + FIELDS * len(chunks), -1, np.int64)
        table[0], table[1] = 0, len(chunks)
        for k, (u0, u1) in enumerate(chunks):
            if not 0 <= u0 < u1:
                raise ValueError(f"chunk [{u0}, {u1}) is empty or negative")
            table[HEADER + FIELDS * k : HEADER + FIELDS * k + 2] = (u0, u1)
        path = str(_directory() / f"{PREFIX}-{os.getpid()}-{uuid.uuid4().hex}")
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_EXCL, 0o600)
        try:
            os.ftruncate(fd, table.nbytes)
            pool = cls(path, fd, mmap.mmap(fd, table.nbytes))
            pool._table[:] = table
            return pool
        except BaseException:
            os.close(fd)
            os.unlink(path)
            raise

    @classmethod
    def open(cls, path: str) -> "LinePool | None":
        """The pool at ``path``, or None when it is gone (its frame is finished)."""
        try:
            fd = os.open(path, os.O_RDWR)
        except FileNotFoundError:
            return None
        try:
            return cls(path, fd, mmap.mmap(fd, os.fstat(fd).st_size))
        except BaseException:
            os.close(fd)
            raise

    @property
    def ticket(self) -> str:
        """What a tracer's render call needs to claim from this pool: its path."""
        return self.path

    def __len__(self) -> int:
        return int(self._table[1])

    def chunk(self, k: int) -> tuple[int, int, int]:
        """Chunk ``k`` as (u0, u1, owner); owner -1: not claimed."""
        u0, u1, owner = self._table[HEADER + FIELDS * k : HEADER + FIELDS * (k + 1)]
        return int(u0), int(u1), int(owner)

    def claim(self, owner: int) -> tuple[int, int] | None:
        """Take the next chunk for ``owner`` (a non-negative id); None when all are taken (or
        the pool is closed)."""
        if self._fd < 0:
            return None
        fcntl.flock(self._fd, fcntl.LOCK_EX)
        try:
            k = int(self._table[0])
            if k >= self._table[1]:
                return None
            self._table[0] = k + 1
            self._table[HEADER + FIELDS * k + 2] = owner
        finally:
            fcntl.flock(self._fd, fcntl.LOCK_UN)
        u0, u1, _ = self.chunk(k)
        return u0, u1

    def claims(self, owner: int) -> Iterator[tuple[int, int]]:
        """Chunks for ``owner``, claimed one at a time, until none is left."""
        while (chunk := self.claim(owner)) is not None:
            yield chunk

    def claimed(self, owner: int | None = None) -> list[tuple[int, int]]:
        """Chunks claimed so far (by ``owner`` only, when given)."""
        chunks = (self.chunk(k) for k in range(len(self)))
        return [(u0, u1) for u0, u1, who in chunks if who >= 0 and (owner is None or who == owner)]

    def unclaimed(self) -> list[tuple[int, int]]:
        """Chunks nobody has claimed yet."""
        return [(u0, u1) for u0, u1, who in map(self.chunk, range(len(self))) if who < 0]

    def close(self) -> None:
        """Unmap and close (the file stays for the other processes); the table is kept as a
        copy, so the pool still reads as it was."""
        if self._fd < 0:
            return
        snapshot = self._table.copy()
        del self._table
        self._buffer.close()
        os.close(self._fd)
        self._fd = -1
        self._table = snapshot

    def unlink(self) -> None:
        """Close and remove the file: tracers that open it later find no pool."""
        self.close()
        try:
            os.unlink(self.path)
        except FileNotFoundError:
            pass

    def __enter__(self) -> "LinePool":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

"""Atomic file writes (a file appears under its name complete, or not at all), and the check
that an output path names a format we write.

The data goes to a temporary file in the target's directory, is flushed to disk, and is
renamed into place; a failed or interrupted write removes the temporary file and leaves any
previous file untouched.
"""

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """A temporary path beside ``path`` for the caller to write; when the block ends without an
    error it is synced to disk, given the usual permissions and renamed to ``path``."""
    path = Path(path)
    fd, tmp_name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        yield tmp
        fd = os.open(tmp, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
        os.chmod(tmp, 0o666 & ~_UMASK)  # mkstemp creates 0600
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def write_atomic(path: str | Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically (:func:`atomic_path`)."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return Path(path)


def _read_umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


_UMASK = _read_umask()  # once, at import: os.umask is process-wide and not thread-safe to probe


def output_file(path: str | Path, formats: tuple[str, ...], kind: str) -> Path:
    """``path`` if its extension is one of ``formats`` and it is not a directory; ValueError
    naming the ``kind`` of format and the ones there are otherwise."""
    path = Path(path)
    if path.suffix.lower() not in formats:
        raise ValueError(
            f"{path}: unknown {kind} format {path.suffix or '(none)'!r}; use one of "
            + ", ".join(formats)
        )
    if path.is_dir():
        raise ValueError(f"{path}: is a directory")
    return path

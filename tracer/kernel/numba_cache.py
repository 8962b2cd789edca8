"""Where numba keeps compiled kernels.

numba's cache is keyed by the source file of each jitted function only: an edit to a helper in
another module does not invalidate the kernels that inline it. We therefore key the cache
directory on a hash of every module in this package, so a changed tracer never reuses stale
machine code. ``TILERENDER_NUMBA_CACHE`` (or ``NUMBA_CACHE_DIR``, when set by the user) chooses
the base directory; the default is ``~/.cache/tilerender/numba``.
"""

import hashlib
import os
from pathlib import Path

_PACKAGE_DIR = Path(__file__).resolve().parents[1]
_MARK = "TILERENDER_NUMBA_CACHE_SET"
"""Environment variable recording the directory ``configure`` chose (see there)."""


def source_digest() -> str:
    """Short hash of the tracer package's Python sources."""
    digest = hashlib.sha256()
    for path in sorted(_PACKAGE_DIR.rglob("*.py")):
        digest.update(path.relative_to(_PACKAGE_DIR).as_posix().encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()[:16]


def cache_base() -> Path:
    """The base directory under which versioned kernel caches live."""
    configured = os.environ.get("TILERENDER_NUMBA_CACHE")
    if configured:
        return Path(configured)
    return Path.home() / ".cache" / "tilerender" / "numba"


def configure() -> Path:
    """Point ``NUMBA_CACHE_DIR`` at the versioned cache directory, unless numba is configured.

    Must run before numba is imported for the setting to take effect; ``tracer/__init__`` does it.
    A value this function set in a parent process (Ray workers inherit the driver's environment)
    is recomputed, so a process never uses kernels of sources other than its own.
    Returns the directory used.
    """
    inherited = os.environ.get("NUMBA_CACHE_DIR")
    ours = inherited is not None and inherited == os.environ.get(_MARK)
    if inherited is not None and not ours and "TILERENDER_NUMBA_CACHE" not in os.environ:
        return Path(inherited)
    path = cache_base() / source_digest()
    os.environ["NUMBA_CACHE_DIR"] = str(path)
    os.environ[_MARK] = str(path)
    return path


def kernels_cached(directory: Path | None = None) -> bool:
    """Whether the path-tracing kernel is in the cache (so a render starts without compiling)."""
    directory = Path(os.environ.get("NUMBA_CACHE_DIR", "")) if directory is None else directory
    return directory.is_dir() and any(directory.rglob("path.trace_pixels*.nbi"))

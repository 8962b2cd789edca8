"""What every command shows and writes: stderr, progress bars, the kernel-compile note, and
output images (whose failures are the user's to fix)."""

from pathlib import Path

import numpy as np
from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

from cli.errors import UsageError
from tracer.io.images import check_output_path, write_image
from tracer.kernel import numba_cache

stderr = Console(stderr=True, highlight=False, soft_wrap=True)


def progress_bar(quiet: bool, counter: str | None = None, transient: bool = True) -> Progress:
    """A progress display on stderr (none when ``quiet``): each task's description, a bar,
    ``counter`` (a column's format, e.g. ``"{task.completed}/{task.total} lines"``), the time
    elapsed and the time left; without ``counter``, the task's ``status`` field and the time
    elapsed only (work of unknown length)."""
    if counter is None:
        columns = [TextColumn("{task.fields[status]}"), TimeElapsedColumn()]
    else:
        columns = [BarColumn(), TextColumn(counter), TimeElapsedColumn(), TimeRemainingColumn()]
    return Progress(
        TextColumn("{task.description}"),
        *columns,
        console=stderr,
        disable=quiet,
        transient=transient,
    )


def note_compiling(quiet: bool) -> bool:
    """Say that the render kernels compile now (unless cached, or ``quiet``); returns whether
    they were cached."""
    cached = numba_cache.kernels_cached()
    if not cached and not quiet:
        stderr.print("compiling render kernels (first run only; cached afterwards)...")
    return cached


def output_path(text: str) -> Path:
    """``-o``'s image path: a format we write, in a directory that exists."""
    try:
        output = check_output_path(text)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    if not output.parent.is_dir():
        raise UsageError(f"{output.parent}: output directory does not exist")
    return output


def write_output(path: Path, rgb: np.ndarray, metadata: dict) -> None:
    """Write an image the command renders; a file that cannot be written is a UsageError."""
    try:
        write_image(path, rgb, metadata)
    except OSError as exc:
        raise UsageError(f"cannot write {path}: {exc.strerror or exc}") from None

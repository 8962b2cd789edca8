"""What every command shows and writes: stderr, progress bars, the kernel-compile note, and
output images (whose failures are the user's to fix)."""

from pathlib import Path

import numpy as np
from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

from cli.errors import CommandFailed, UsageError
from tracer.io.images import check_output_path, write_image
from tracer.io.layers import check_layers_path, layer_as_rgb, write_layers
from tracer.kernel import numba_cache
from tracer.post.denoise import DenoiseFailed, DenoiserUnavailable
from tracer.post.frame_layers import default_layer, frame_layers, rendered_layers
from tracer.scene import format as fmt

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
    """``-o``'s image path: a format we write (an image, or a bundle of layers), in a directory
    that exists."""
    try:
        if Path(text).suffix.lower() == ".npz":
            output = check_layers_path(text)
        else:
            output = check_output_path(text)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    if not output.parent.is_dir():
        raise UsageError(f"{output.parent}: output directory does not exist")
    return output


def check_layer_choice(layer: str | None, settings: fmt.RenderSettings) -> None:
    """A UsageError, before anything renders, for a ``--layer`` the render will not have."""
    if layer is not None and layer not in (present := rendered_layers(settings)):
        raise UsageError(
            f"--layer {layer}: this render has the layers {', '.join(present)} "
            "(--aov adds the AOVs, --denoise the denoised layer)"
        )


def write_output(
    path: Path,
    rgb: np.ndarray,
    metadata: dict,
    aov: np.ndarray | None = None,
    settings: fmt.RenderSettings | None = None,
    layer: str | None = None,
) -> dict:
    """Write a frame the command renders: its layers (``tracer.post.frame_layers``: the
    denoised one made here when ``settings`` ask for it) to a ``.npz``, or to a ``.exr`` when
    there are several and no ``layer`` is named, else ``layer`` (default ``default_layer``) as
    an image (as it is in float formats; a PNG maps normals and depth for viewing). Returns what
    making the layers took (the denoiser's report, in the metadata too). A file that cannot be
    written is a UsageError; a missing denoiser a CommandFailed."""
    settings = settings or fmt.RenderSettings()
    try:
        layers, info = frame_layers(rgb, aov, settings)
    except (DenoiserUnavailable, DenoiseFailed) as exc:
        raise CommandFailed(str(exc)) from None
    metadata = {**metadata, **info}
    try:
        suffix = path.suffix.lower()
        if suffix == ".npz" or (suffix == ".exr" and len(layers) > 1 and layer is None):
            write_layers(path, layers, metadata)
        else:
            shown = layer_as_rgb(layers, layer or default_layer(settings), view=suffix == ".png")
            write_image(path, shown, metadata)
    except OSError as exc:
        raise UsageError(f"cannot write {path}: {exc.strerror or exc}") from None
    return info


def describe_denoise(info: dict) -> str:
    """What the denoiser did, for the command's summary line ('' if it did not run)."""
    done = info.get("denoise")
    if not done:
        return ""
    guides = "+".join(done["guides"]) or "no"
    return f", denoised ({done['quality']}, {guides} guides) in {done['seconds']:.2f} s"

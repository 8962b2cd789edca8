"""Rendering in this process, without Ray: a still with a progress bar of lines."""

import time
from pathlib import Path

import numpy as np

from cli.output import describe_denoise, note_compiling, progress_bar, stderr, write_output
from tracer.compiled.scene import CompiledScene
from tracer.integrators.aov import CHANNELS
from tracer.integrators.effects import effect_plan
from tracer.integrators.kernel_choice import plan_report
from tracer.io.metadata import id_names, image_metadata
from tracer.render import render_image, render_lines
from tracer.scene import format as fmt


def warm_up(scene: CompiledScene, settings: fmt.RenderSettings, quiet: bool) -> None:
    """Compile the render kernel (or load it from the cache) with a one-pixel render."""
    cached = note_compiling(quiet)
    start = time.perf_counter()
    tiny = fmt.override(scene.camera, width=1, height=1)
    render_lines(scene, 0, 1, tiny, fmt.override(settings, spp=1), threads=1)
    if not cached and not quiet:
        stderr.print(f"compiled in {time.perf_counter() - start:.1f} s")


def render_to_file(
    scene: CompiledScene,
    camera: fmt.Camera,
    settings: fmt.RenderSettings,
    outputs: list[Path],
    threads: int | None,
    quiet: bool,
    label: str,
    layer: str | None = None,
) -> float:
    """Render with a progress bar and write every output (``layer`` as ``write_output``);
    returns seconds spent rendering."""
    warm_up(scene, settings, quiet)
    samples_total = camera.width * camera.height * settings.spp
    start = time.perf_counter()
    aov = None
    if settings.renders_aovs:
        aov = np.empty((camera.height, camera.width, CHANNELS), np.float32)
    with progress_bar(quiet, "{task.completed}/{task.total} lines") as progress:
        task = progress.add_task(label, total=camera.height)
        rays = []

        def on_lines(part) -> None:
            progress.advance(task, part.y1 - part.y0)
            rays.append(int(part.rays.sum()))
            if part.aov is not None:
                aov[part.y0 : part.y1] = part.aov

        image, _ = render_image(scene, camera, settings, threads=threads, on_lines=on_lines)
    seconds = time.perf_counter() - start
    plan = plan_report(effect_plan(scene, settings), settings)
    metadata = image_metadata(
        camera, settings, plan, seconds, sum(rays), "in-process", **id_names(scene.state, settings)
    )
    for path in outputs:
        info = write_output(path, image, metadata, aov, settings, layer)
    if not quiet:
        rate = samples_total / seconds / 1e6
        names = ", ".join(str(p) for p in outputs)
        stderr.print(
            f"wrote {names}: {camera.width}x{camera.height}, {settings.spp} spp, "
            f"{seconds:.2f} s, {rate:.2f} M samples/s, {sum(rays) / seconds / 1e6:.2f} M rays/s"
            f"{describe_denoise(info)}"
        )
    return seconds

"""Rendering through the coordinator: tracer actors on Ray (embedded unless an address is
given), a still or an animation, at a fixed spp or in waves to a quality goal."""

import argparse
import time
from pathlib import Path

from cli.errors import CommandFailed
from cli.output import describe_denoise, note_compiling, progress_bar, stderr, write_output
from cluster.balancing import DEFAULT_BALANCER
from cluster.jobs import embedded_ray_cpus
from cluster.progressive import Goal, ProgressiveFrame, render_progressive
from tracer.io.metadata import id_names, image_metadata
from tracer.request import FrameRequest
from tracer.scene.model import SceneState


def render_through_cluster(
    state: SceneState,
    frames: list[int] | None,
    outputs: list[Path],
    args: argparse.Namespace,
    goal: Goal | None,
) -> None:
    """Start (or join) Ray and the tracers, render the still or each frame, write the files."""
    from cluster.connect import connect, disconnect
    from cluster.coordinator import Coordinator
    from cluster.scene_graph import SceneGraph

    note_compiling(args.quiet)
    num_cpus = embedded_ray_cpus(args.ray_address, args.tracers, args.threads)
    try:
        connection = connect(args.ray_address, num_cpus=num_cpus)
    except RuntimeError as exc:  # the embedded Ray did not start
        raise CommandFailed(f"Ray did not start: {str(exc).splitlines()[0]}") from None
    try:
        coordinator = Coordinator(
            SceneGraph(state),
            tracers=args.tracers,
            cpus_per_tracer=args.threads,
            balancer=args.balancer or DEFAULT_BALANCER,
        )
        try:
            if frames is None:
                render_still(coordinator, outputs[0], args, goal)
            elif goal is not None:
                render_frames_progressive(coordinator, frames, outputs, args, goal)
            else:
                render_frames(coordinator, frames, outputs, args)
        finally:
            coordinator.close()
    finally:
        if connection.started:
            disconnect()


def frame_metadata(done, args: argparse.Namespace, state: SceneState) -> dict:
    """A coordinator frame's image metadata (``state``: the scene, for the names of ids)."""
    rays = int(done.rays.sum()) if done.rays is not None else None
    return image_metadata(
        done.camera,
        done.settings,
        done.effects,
        done.wall_seconds,
        rays,
        "ray",
        frame=done.frame,
        scene_version=done.version,
        tracers=len(done.split),
        balancer=args.balancer or DEFAULT_BALANCER,
        **id_names(state, done.settings),
    )


def progressive_frame_metadata(
    done, args: argparse.Namespace, progress: ProgressiveFrame, state: SceneState
):
    """A progressive frame's metadata: its last wave's, with the spp and seconds of all waves
    (rays are counted per wave only, so none are given)."""
    metadata = frame_metadata(done, args, state)
    metadata["render"]["spp"] = progress.spp
    metadata["seconds"] = round(progress.elapsed, 3)
    metadata["rays"] = None
    metadata["progressive"] = progress.summary()
    return metadata


def render_progressive_frame(coordinator, goal: Goal, frame: int, label: str, quiet: bool):
    """One frame rendered in waves to ``goal``, with a progress line of spp and error;
    returns ``(progress, last coordinator frame)``."""
    last = []
    with progress_bar(quiet) as bar:
        task = bar.add_task(label, total=None, status="first wave")

        def on_part(progress, done) -> None:
            last[:] = [done]
            if not progress.waves:
                return
            wave = progress.waves[-1]  # the estimate and the samples it was made at
            if wave.error is not None:
                bar.update(task, status=f"{wave.spp} spp, est. error {wave.error:.2%}")
            else:
                bar.update(task, status=f"{wave.spp} spp, error not estimable yet")

        progress = render_progressive(coordinator, goal, frame, on_part=on_part)
    return progress, last[0]


def describe_progressive(progress: ProgressiveFrame) -> str:
    goal = progress.goal
    target = f" (target {goal.target_error:.2%})" if goal.target_error is not None else ""
    reason = {
        "target_error": "target reached",
        "time_budget": "time budget spent",
        "max_spp": "--max-spp reached",
    }[progress.stopped]
    error = "not estimable yet" if progress.error is None else f"{progress.error:.2%}"
    of = (
        " of the denoised image"
        if progress.waves and progress.waves[-1].error_of == "denoised"
        else ""
    )
    return (
        f"{progress.spp} spp in {len(progress.waves)} waves, estimated error{of} "
        f"{error}{target}, {reason}"
    )


def render_still(coordinator, output: Path, args: argparse.Namespace, goal: Goal | None) -> None:
    if goal is not None:
        progress, done = render_progressive_frame(
            coordinator, goal, 0, Path(args.scene).name, args.quiet
        )
        info = write_output(
            output,
            progress.image,
            progressive_frame_metadata(done, args, progress, coordinator.graph.state),
            progress.aov,
            done.settings,
            args.layer,
        )
        if not args.quiet:
            camera = done.camera
            stderr.print(
                f"wrote {output}: {camera.width}x{camera.height}, "
                f"{describe_progressive(progress)}, {progress.elapsed:.2f} s"
                f"{describe_denoise(info)}"
            )
        return
    with progress_bar(args.quiet, "{task.completed}/{task.total} frames") as progress:
        task = progress.add_task(Path(args.scene).name, total=1)
        done = coordinator.render_frame(FrameRequest(0))
        progress.advance(task)
    tracers = len(done.split)
    metadata = frame_metadata(done, args, coordinator.graph.state)
    info = write_output(output, done.rgb, metadata, done.aov, done.settings, args.layer)
    if not args.quiet:
        camera, spp = done.camera, done.settings.spp
        rate = camera.width * camera.height * spp / max(done.wall_seconds, 1e-9) / 1e6
        stderr.print(
            f"wrote {output}: {camera.width}x{camera.height}, {spp} spp, "
            f"{done.wall_seconds:.2f} s, {rate:.2f} M samples/s, "
            f"{done.rays.sum() / max(done.wall_seconds, 1e-9) / 1e6:.2f} M rays/s, {tracers} tracer"
            f"{'s' if tracers != 1 else ''}, idle {done.idle_percent:.1f} %{describe_denoise(info)}"
        )


def render_frames_progressive(coordinator, frames, outputs, args, goal: Goal) -> None:
    """Render an animation frame by frame, each in waves to ``goal``."""
    written = 0
    try:
        for number, path in zip(frames, outputs, strict=True):
            coordinator.graph.frame_commit(number)
            label = f"{Path(args.scene).name} frame {number}"
            progress, done = render_progressive_frame(coordinator, goal, number, label, args.quiet)
            metadata = progressive_frame_metadata(done, args, progress, coordinator.graph.state)
            write_output(path, progress.image, metadata, progress.aov, done.settings, args.layer)
            written += 1
            if not args.quiet:
                stderr.print(
                    f"frame {number}: {path.name}, {describe_progressive(progress)}, "
                    f"{progress.elapsed:.2f} s"
                )
    except KeyboardInterrupt:
        raise KeyboardInterrupt(f"interrupted; {written} of {len(frames)} frames written") from None


def render_frames(coordinator, frames: list[int], outputs: list[Path], args) -> None:
    """Render an animation frame by frame (pipelined), writing each as it completes."""
    written = 0
    start = time.perf_counter()
    idle = []
    try:
        with progress_bar(args.quiet, "{task.completed}/{task.total} frames") as progress:
            task = progress.add_task(Path(args.scene).name, total=len(frames))
            for done, path in zip(coordinator.render_animation(frames), outputs, strict=True):
                tracers = len(done.split)
                metadata = frame_metadata(done, args, coordinator.graph.state)
                write_output(path, done.rgb, metadata, done.aov, done.settings, args.layer)
                written += 1
                idle.append(done.idle_percent)
                progress.advance(task)
                if not args.quiet:
                    extra = ""
                    if done.failures or done.duplicates:
                        extra = f", {done.failures} lost, {done.duplicates} duplicated"
                    progress.console.print(
                        f"frame {done.frame}: {path.name}, {done.wall_seconds:.3f} s, "
                        f"idle {done.idle_percent:.1f} %, {tracers} tracer"
                        f"{'s' if tracers != 1 else ''}{extra}"
                    )
    except KeyboardInterrupt:
        raise KeyboardInterrupt(f"interrupted; {written} of {len(frames)} frames written") from None
    if not args.quiet:
        seconds = time.perf_counter() - start
        stderr.print(
            f"wrote {written} frames {outputs[0].name} .. {outputs[-1].name}: "
            f"{seconds / max(written, 1):.3f} s per frame, mean idle "
            f"{sum(idle) / max(len(idle), 1):.1f} %"
        )

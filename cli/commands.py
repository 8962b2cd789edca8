"""What each ``tilerender`` sub-command does."""

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import pydantic
from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

from cli.main import CommandFailed, UsageError
from cluster.balance import DEFAULT_BALANCER
from tracer.compiled.scene import CompiledScene, compile_scene
from tracer.errors import SceneError, format_validation_error
from tracer.integrators.effects import effect_plan
from tracer.io.images import check_output_path, write_image
from tracer.kernel import numba_cache
from tracer.kernel.threads import default_threads
from tracer.render import render_image, render_lines
from tracer.request import FrameRequest
from tracer.scene import format as fmt
from tracer.scene.loader import load_scene
from tracer.scene.model import SceneState

REPO_SCENES = Path(__file__).resolve().parents[1] / "scenes"

stderr = Console(stderr=True, highlight=False, soft_wrap=True)


def run(args: argparse.Namespace) -> int:
    try:
        if args.command == "render":
            return cmd_render(args)
        if args.command == "samples":
            return cmd_samples(args)
        if args.command == "serve":
            return cmd_serve(args)
        if args.command == "schema":
            print(scene_schema_json())
            return 0
        if args.command == "plan":
            return cmd_plan(args)
        if args.command == "bench":
            return cmd_bench(args)
        return cmd_info(args)
    except BrokenPipeError:
        raise
    except (SceneError, ValueError, OSError) as exc:  # incl. ClusterUnreachable
        raise UsageError(str(exc).splitlines()[0]) from None
    except RuntimeError as exc:  # ClusterError, or Ray failing to start
        raise CommandFailed(str(exc).splitlines()[0] or type(exc).__name__) from None


def load(path: str) -> CompiledScene:
    return compile_scene(load_scene(path))


def settings_for(scene: CompiledScene | SceneState, args: argparse.Namespace):
    """The scene's camera and render settings with the command line's overrides applied."""
    try:
        camera = fmt.override(scene.camera, width=args.width, height=args.height)
        settings = fmt.override(
            scene.render,
            spp=args.spp,
            seed=args.seed,
            max_depth=args.max_depth,
            integrator=args.integrator,
        )
    except pydantic.ValidationError as exc:
        raise UsageError(format_validation_error(exc)) from None
    return camera, settings


def warm_up(scene: CompiledScene, settings: fmt.RenderSettings, quiet: bool) -> None:
    """Compile the render kernel (or load it from the cache) with a one-pixel render."""
    cached = numba_cache.kernels_cached()
    if not cached and not quiet:
        stderr.print("compiling render kernels (first run only; cached afterwards)...")
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
) -> float:
    """Render with a progress bar and write every output; returns seconds spent rendering."""
    warm_up(scene, settings, quiet)
    samples_total = camera.width * camera.height * settings.spp
    start = time.perf_counter()
    with Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        TextColumn("{task.completed}/{task.total} lines"),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        console=stderr,
        disable=quiet,
        transient=True,
    ) as progress:
        task = progress.add_task(label, total=camera.height)
        rays = []

        def on_lines(part) -> None:
            progress.advance(task, part.y1 - part.y0)
            rays.append(int(part.rays.sum()))

        image, _ = render_image(scene, camera, settings, threads=threads, on_lines=on_lines)
    seconds = time.perf_counter() - start
    metadata = {
        "renderer": "tilerender",
        "version": tracer_version(),
        "camera": camera.model_dump(),
        "render": settings.model_dump(),
        "effect_plan": effect_plan(scene, settings).to_json(),
        "seconds": round(seconds, 3),
        "rays": sum(rays),
        "executor": "in-process",
    }
    for path in outputs:
        write_image(path, image, metadata)
    if not quiet:
        rate = samples_total / seconds / 1e6
        names = ", ".join(str(p) for p in outputs)
        stderr.print(
            f"wrote {names}: {camera.width}x{camera.height}, {settings.spp} spp, "
            f"{seconds:.2f} s, {rate:.2f} M samples/s, {sum(rays) / seconds / 1e6:.2f} M rays/s"
        )
    return seconds


def tracer_version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("tilerender")
    except PackageNotFoundError:
        return "unknown"


def cmd_render(args: argparse.Namespace) -> int:
    """Render through the coordinator: tracer actors on Ray (embedded unless --ray-address)."""
    output = check_output_path(args.output)
    if not output.parent.is_dir():
        raise UsageError(f"{output.parent}: output directory does not exist")
    from cluster.balance import make_balancer

    if args.balancer is not None:
        make_balancer(args.balancer)  # a wrong name fails before Ray starts
    goal = quality_goal(args)  # bad --target-error / --time-budget combinations fail early too
    state = load_scene(args.scene)
    camera, settings = settings_for(state, args)
    state = dataclasses.replace(state, camera=camera, render=settings)
    frames = frame_selection(state, args.frames)
    if runs_in_process(args, camera, settings, still=frames is None, progressive=goal is not None):
        scene, label = compile_scene(state), Path(args.scene).name
        render_to_file(scene, camera, settings, [output], args.threads, args.quiet, label)
        return 0
    if frames is None:
        outputs = [output]
    else:
        digits = max(4, len(str(frames[-1])))
        outputs = [output.with_name(f"{output.stem}_{f:0{digits}d}{output.suffix}") for f in frames]
    render_through_cluster(state, frames, outputs, args)
    return 0


IN_PROCESS_SAMPLES = 1 << 22
"""Most pixel samples (width x height x spp) of a still that ``render`` runs in its own process
unless told otherwise: about 1-3 s of rendering on 2 cores, while starting and stopping the
embedded Ray alone takes about 4.5 s (docs/performance.md, Start-up)."""


def runs_in_process(
    args: argparse.Namespace,
    camera: fmt.Camera,
    settings: fmt.RenderSettings,
    still: bool,
    progressive: bool,
) -> bool:
    """Whether ``render`` renders here, without Ray: ``--in-process``, or by default a small
    still at a fixed spp with no cluster option given. ``--no-in-process`` never does."""
    cluster_options = [
        flag
        for flag, value in (
            ("--tracers", args.tracers),
            ("--balancer", args.balancer),
            ("--ray-address", args.ray_address),
        )
        if value is not None
    ]
    if args.in_process:
        if cluster_options:
            raise UsageError(f"--in-process renders without Ray: drop {', '.join(cluster_options)}")
        if not still or progressive:
            raise UsageError(
                "--in-process renders a still at a fixed --spp; animations, --target-error and "
                "--time-budget go through the coordinator"
            )
        return True
    if args.in_process is False or cluster_options or not still or progressive:
        return False
    return camera.width * camera.height * settings.spp <= IN_PROCESS_SAMPLES


def quality_goal(args: argparse.Namespace, frames: int = 1):
    """The progressive goal of ``--target-error`` / ``--time-budget`` (None without them);
    the budget is shared evenly by ``frames``."""
    from cluster.progressive import DEFAULT_MAX_SPP, PARTS, Goal

    if args.target_error is None and args.time_budget is None:
        if args.max_spp is not None:
            raise UsageError("--max-spp applies with --target-error or --time-budget only")
        return None
    if args.spp is not None:
        raise UsageError(
            "--spp fixes the samples per pixel; with --target-error or --time-budget the waves "
            "choose them (cap them with --max-spp)"
        )
    max_spp = args.max_spp or DEFAULT_MAX_SPP
    if max_spp < PARTS:
        raise UsageError(
            f"--max-spp must be at least {PARTS} (a wave is {PARTS} independent parts of at "
            "least one sample each)"
        )
    budget = None if args.time_budget is None else args.time_budget / frames
    return Goal(target_error=args.target_error, time_budget=budget, max_spp=max_spp)


def frame_selection(state: SceneState, text: str | None) -> list[int] | None:
    """The animation frames ``--frames`` selects (all by default); None for a still scene."""
    animation = state.animation
    if animation is None:
        if text is not None:
            raise UsageError("--frames: the scene has no animation")
        return None
    count = animation.frames
    if text is None:
        return list(range(count))
    first, sep, last = text.strip().partition("-")
    try:
        a, b = int(first), int(last) if sep else int(first)
    except ValueError:
        raise UsageError(f"--frames: expected N or FIRST-LAST, got {text!r}") from None
    if not 0 <= a <= b < count:
        raise UsageError(f"--frames: {text!r} is not within the animation's frames 0-{count - 1}")
    return list(range(a, b + 1))


def render_through_cluster(
    state: SceneState, frames: list[int] | None, outputs: list[Path], args: argparse.Namespace
) -> None:
    """Start (or join) Ray and the tracers, render the still or each frame, write the files."""
    from cluster.connect import connect, disconnect
    from cluster.coordinator import Coordinator
    from cluster.scene_graph import SceneGraph

    quiet = args.quiet
    if not numba_cache.kernels_cached() and not quiet:
        stderr.print("compiling render kernels (first run only; cached afterwards)...")
    num_cpus = None
    if args.ray_address is None and args.threads:
        # The embedded Ray gets enough logical CPUs for every tracer to have --threads of them
        # (a tracer that does not fit would wait for CPUs forever).
        num_cpus = max(default_threads(), (args.tracers or 1) * args.threads)
    connection = connect(args.ray_address, num_cpus=num_cpus)
    try:
        coordinator = Coordinator(
            SceneGraph(state),
            tracers=args.tracers,
            cpus_per_tracer=args.threads,
            balancer=args.balancer or DEFAULT_BALANCER,
        )
        try:
            if frames is None:
                render_still(coordinator, outputs[0], args)
            else:
                render_frames(coordinator, frames, outputs, args)
        finally:
            coordinator.close()
    finally:
        if connection.started:
            disconnect()


def frame_metadata(done, args: argparse.Namespace, tracers: int) -> dict:
    return {
        "renderer": "tilerender",
        "version": tracer_version(),
        "camera": done.camera.model_dump(),
        "render": done.settings.model_dump(),
        "effect_plan": done.effects,
        "seconds": round(done.wall_seconds, 3),
        "rays": int(done.rays.sum()) if done.rays is not None else None,
        "frame": done.frame,
        "scene_version": done.version,
        "tracers": tracers,
        "balancer": args.balancer or DEFAULT_BALANCER,
        "executor": "ray",
    }


def _progress(quiet: bool) -> Progress:
    return Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        TextColumn("{task.completed}/{task.total} frames"),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        console=stderr,
        disable=quiet,
        transient=True,
    )


def progressive_frame_metadata(done, args: argparse.Namespace, progress) -> dict:
    """A progressive frame's metadata: its last wave's, with the spp and seconds of all waves
    (rays are counted per wave only, so none are given)."""
    metadata = frame_metadata(done, args, len(done.split))
    metadata["render"]["spp"] = progress.spp
    metadata["seconds"] = round(progress.elapsed, 3)
    metadata["rays"] = None
    metadata["progressive"] = progressive_metadata(progress)
    return metadata


def progressive_metadata(progress) -> dict:
    """What a progressive render adds to an image's metadata."""
    goal = progress.goal
    return {
        "target_error": goal.target_error,
        "time_budget": goal.time_budget,
        "max_spp": goal.max_spp,
        "error_estimate": progress.error,
        "spp": progress.spp,
        "waves": len(progress.waves),
        "spot_checks": progress.waves[-1].checked if progress.waves else 0,
        "stopped": progress.stopped,
    }


def render_progressive_frame(coordinator, goal, frame: int, label: str, quiet: bool):
    """One frame rendered in waves to ``goal``, with a progress line of spp and error;
    returns ``(progress, last coordinator frame)``."""
    from cluster.progressive import render_progressive

    last = []
    with Progress(
        TextColumn("{task.description}"),
        TextColumn("{task.fields[status]}"),
        TimeElapsedColumn(),
        console=stderr,
        disable=quiet,
        transient=True,
    ) as bar:
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


def describe_progressive(progress) -> str:
    goal = progress.goal
    target = f" (target {goal.target_error:.2%})" if goal.target_error is not None else ""
    reason = {
        "target_error": "target reached",
        "time_budget": "time budget spent",
        "max_spp": "--max-spp reached",
    }[progress.stopped]
    error = "not estimable yet" if progress.error is None else f"{progress.error:.2%}"
    return (
        f"{progress.spp} spp in {len(progress.waves)} waves, estimated error "
        f"{error}{target}, {reason}"
    )


def render_still(coordinator, output: Path, args: argparse.Namespace) -> None:
    goal = quality_goal(args)
    if goal is not None:
        progress, done = render_progressive_frame(
            coordinator, goal, 0, Path(args.scene).name, args.quiet
        )
        write_image(output, progress.image, progressive_frame_metadata(done, args, progress))
        if not args.quiet:
            camera = done.camera
            stderr.print(
                f"wrote {output}: {camera.width}x{camera.height}, "
                f"{describe_progressive(progress)}, {progress.elapsed:.2f} s"
            )
        return
    with _progress(args.quiet) as progress:
        task = progress.add_task(Path(args.scene).name, total=1)
        done = coordinator.render_frame(FrameRequest(0))
        progress.advance(task)
    tracers = len(done.split)
    write_image(output, done.rgb, frame_metadata(done, args, tracers))
    if not args.quiet:
        camera, spp = done.camera, done.settings.spp
        rate = camera.width * camera.height * spp / max(done.wall_seconds, 1e-9) / 1e6
        stderr.print(
            f"wrote {output}: {camera.width}x{camera.height}, {spp} spp, "
            f"{done.wall_seconds:.2f} s, {rate:.2f} M samples/s, "
            f"{done.rays.sum() / max(done.wall_seconds, 1e-9) / 1e6:.2f} M rays/s, {tracers} tracer"
            f"{'s' if tracers != 1 else ''}, idle {done.idle_percent:.1f} %"
        )


def render_frames_progressive(coordinator, frames, outputs, args, goal) -> None:
    """Render an animation frame by frame, each in waves to ``goal``."""
    written = 0
    try:
        for number, path in zip(frames, outputs, strict=True):
            coordinator.graph.frame_commit(number)
            label = f"{Path(args.scene).name} frame {number}"
            progress, done = render_progressive_frame(coordinator, goal, number, label, args.quiet)
            write_image(path, progress.image, progressive_frame_metadata(done, args, progress))
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
    goal = quality_goal(args, len(frames))
    if goal is not None:
        render_frames_progressive(coordinator, frames, outputs, args, goal)
        return
    written = 0
    start = time.perf_counter()
    idle = []
    try:
        with _progress(args.quiet) as progress:
            task = progress.add_task(Path(args.scene).name, total=len(frames))
            for done, path in zip(coordinator.render_animation(frames), outputs, strict=True):
                tracers = len(done.split)
                write_image(path, done.rgb, frame_metadata(done, args, tracers))
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


def cmd_bench(args: argparse.Namespace) -> int:
    """``bench accuracy``: the accuracy study (cli.accuracy), with a progress bar per scene."""
    from cli.accuracy import DEFAULT_CACHE, REPO_ROOT, StudyOptions, refresh_time_to, run_study
    from cli.accuracy_report import load_previous, write_report

    root = REPO_SCENES
    available = {path.parent.name: path for path in sample_scene_files(root)}
    names = args.scenes or sorted(available)
    unknown = [n for n in names if n not in available]
    if unknown:
        raise UsageError(
            f"--scenes: no sample scene {', '.join(unknown)} (have: {', '.join(sorted(available))})"
        )
    quick = args.quick

    def pick(value, default, quick_value):
        return value if value is not None else quick_value if quick else default

    options = StudyOptions(
        scenes=tuple(available[n] for n in names),
        pixels=pick(args.pixels, 128 * 96, 1024),
        max_spp=pick(args.max_spp, 1024, 64),
        reference_factor=pick(args.reference_factor, 16, 8),
        repeats=pick(args.repeats, 7, 2),
        effect_spp=pick(args.effect_spp, 32, 4),
        seed=args.seed,
        threads=args.threads,
        cache_dir=Path(args.cache) if args.cache else DEFAULT_CACHE,
    )
    out = Path(args.out) if args.out else REPO_ROOT / "bench" / "results" / "accuracy"
    if out.exists() and not out.is_dir():
        raise UsageError(f"--out: {out} is not a directory")
    command = " ".join(["tilerender", *getattr(args, "argv", ["bench", "accuracy"])])
    docs_page = REPO_ROOT / "docs" / "accuracy.md" if args.docs else None
    if args.report_only:
        results, images = load_previous(out)
        refresh_time_to(results)
        command = results.get("command", command)
        written = write_report(results, images, out, docs_page, command)
        if not args.quiet:
            stderr.print(f"rewrote the report from {out}: {len(written)} files")
        return 0
    if not numba_cache.kernels_cached() and not args.quiet:
        stderr.print("compiling render kernels (first run only; cached afterwards)...")
    with Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        TextColumn("{task.percentage:>3.0f}%"),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        console=stderr,
        disable=args.quiet,
    ) as progress:
        current = {}

        def on_start(name: str, total: int) -> None:
            current["name"] = name
            current["task"] = progress.add_task(name, total=total)

        def on_phase(phase: str) -> None:
            progress.update(current["task"], description=f"{current['name']}: {phase}")

        def on_samples(n: int) -> None:
            progress.advance(current["task"], n)

        results, images = run_study(options, on_start, on_samples, on_phase)
        for task in progress.tasks:
            progress.update(task.id, completed=task.total)
    results["command"] = command
    written = write_report(results, images, out, docs_page, command)
    if not args.quiet:
        stderr.print(f"wrote {len(written)} files into {out}" + (" and docs/" if args.docs else ""))
    return 0


def sample_scene_files(root: Path) -> list[Path]:
    """Each sample scene under ``root``: a folder's scene.json, else its one glTF/GLB file."""
    found = []
    for folder in sorted(p for p in root.iterdir() if p.is_dir()):
        scene = folder / "scene.json"
        if scene.is_file():
            found.append(scene)
            continue
        gltf = sorted(folder.glob("*.gltf")) + sorted(folder.glob("*.glb"))
        if len(gltf) == 1:
            found.append(gltf[0])
    return found


def cmd_samples(args: argparse.Namespace) -> int:
    root = Path(args.scenes) if args.scenes else REPO_SCENES
    if not root.is_dir():
        raise UsageError(f"{root}: no such scenes directory")
    scenes = sample_scene_files(root)
    if not scenes:
        raise UsageError(f"{root}: no sample scenes found")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for path in scenes:
        scene = load(str(path))
        settings = fmt.override(scene.render, spp=args.spp)
        name = path.parent.name
        render_to_file(
            scene,
            scene.camera,
            settings,
            [out / f"{name}.png", out / f"{name}.exr"],
            args.threads,
            args.quiet,
            name,
        )
    if not args.quiet:
        stderr.print(f"{len(scenes)} sample scenes rendered into {out}/")
    return 0


def scene_schema_json() -> str:
    """The JSON Schema of scene files, as committed in docs/scene-schema.json."""
    return json.dumps(fmt.SceneFile.model_json_schema(), indent=2, sort_keys=True)


def cmd_plan(args: argparse.Namespace) -> int:
    scene = load(args.scene)
    try:
        settings = fmt.override(scene.render, integrator=args.integrator, max_depth=args.max_depth)
    except pydantic.ValidationError as exc:
        raise UsageError(format_validation_error(exc)) from None
    report = {
        "scene": args.scene,
        "integrator": settings.integrator,
        **effect_plan(scene, settings).to_json(),
    }
    json.dump(report, sys.stdout, indent=2)
    print()
    return 0


def cmd_info(args: argparse.Namespace) -> int:
    scene = load(args.scene)
    stats = scene.stats
    report = {
        "scene": args.scene,
        "triangles": stats.triangles,
        "zero_area_triangles_dropped": stats.degenerate_triangles,
        "emissive_triangles": stats.emissive_triangles,
        "bounds": {"min": stats.bounds_min, "max": stats.bounds_max},
        "materials": list(scene.material_names),
        "textures": {
            name: [int(image.shape[1]), int(image.shape[0])]
            for name, image in scene.textures.sources
        },
        "instances": scene.stats.instances,
        "nodes": len(scene.state.nodes),
        "bvh_nodes": sum(int(pool.bounds.shape[0]) for pool in scene.pools),
        "bytes_per_triangle": round(scene.nbytes / max(1, stats.triangles), 1),
        "camera": scene.camera.model_dump(),
        "render": scene.render.model_dump(),
    }
    json.dump(report, sys.stdout, indent=2)
    print()
    return 0


def serve_settings(args: argparse.Namespace):
    """The service's settings: TILERENDER_* variables, overridden by the flags given."""
    from api.settings import Settings

    num_cpus = None
    if args.ray_address is None and args.threads:  # every tracer must fit (as for render)
        num_cpus = max(default_threads(), (args.tracers or 1) * args.threads)
    try:
        return Settings.from_env(
            num_cpus=num_cpus,
            data_dir=args.data_dir,
            db_path=args.db,
            token=args.token,
            cors_origins=args.cors_origin,
            ray_address=args.ray_address,
            tracers=args.tracers,
            threads=args.threads,
            balancer=args.balancer,
        )
    except pydantic.ValidationError as exc:
        raise UsageError(format_validation_error(exc)) from None


def cmd_serve(args: argparse.Namespace) -> int:
    """Run the HTTP service until interrupted; prints the viewer's URL once listening."""
    import socket

    import uvicorn

    from api.app import create_app

    settings = serve_settings(args)
    if settings.ray_address is not None:  # fail fast, before anything starts
        from cluster.connect import probe

        probe(settings.ray_address.removeprefix("ray://"))
    family = socket.AF_INET6 if ":" in args.host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    # Accepted connections inherit this: without it a response written in two parts waits
    # for the client's delayed ACK (about 40 ms per request on keep-alive connections).
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    try:
        sock.bind((args.host, args.port))
    except OSError as exc:
        sock.close()
        raise UsageError(
            f"cannot listen on {args.host}:{args.port}: {exc.strerror or exc}"
        ) from None
    port = sock.getsockname()[1]
    host = f"[{args.host}]" if family == socket.AF_INET6 else args.host
    url = f"http://{host}:{port}/"
    cluster = settings.ray_address or "an embedded local Ray"
    fragment = f"#token={settings.token}" if settings.token else ""
    print(f"tilerender: viewer at {url}{fragment}", flush=True)
    stderr.print(
        f"serving the API at {url}v1 (docs at {url}docs) on {cluster}; data in "
        f"{settings.data_dir}; Ctrl-C stops"
    )
    config = uvicorn.Config(
        create_app(settings),
        log_level=args.log_level,
        access_log=args.log_level in ("info", "debug"),
        timeout_graceful_shutdown=5,
    )
    server = uvicorn.Server(config)
    try:
        server.run(sockets=[sock])
    except KeyboardInterrupt:  # uvicorn re-raises the signal once it has shut down cleanly
        pass
    stderr.print("tilerender: stopped")
    return 0

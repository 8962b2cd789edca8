"""What each ``tilerender`` sub-command does."""

import argparse
import json
import sys
import time
from pathlib import Path

import pydantic
from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

from cli.main import UsageError
from tracer import numba_cache
from tracer import scene_format as fmt
from tracer.compile import CompiledScene, compile_scene
from tracer.effects import effect_plan
from tracer.errors import SceneError
from tracer.image_io import check_output_path, write_image
from tracer.loader import format_validation_error, load_scene
from tracer.render import render_image, render_lines

REPO_SCENES = Path(__file__).resolve().parents[1] / "scenes"

stderr = Console(stderr=True, highlight=False, soft_wrap=True)


def run(args: argparse.Namespace) -> int:
    try:
        if args.command == "render":
            return cmd_render(args)
        if args.command == "samples":
            return cmd_samples(args)
        if args.command == "schema":
            print(scene_schema_json())
            return 0
        if args.command == "plan":
            return cmd_plan(args)
        return cmd_info(args)
    except BrokenPipeError:
        raise
    except (SceneError, ValueError, OSError) as exc:
        raise UsageError(str(exc).splitlines()[0]) from None


def load(path: str) -> CompiledScene:
    return compile_scene(load_scene(path))


def settings_for(scene: CompiledScene, args: argparse.Namespace):
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
        image, _ = render_image(
            scene,
            camera,
            settings,
            threads=threads,
            on_lines=lambda part: progress.advance(task, part.y1 - part.y0),
        )
    seconds = time.perf_counter() - start
    metadata = {
        "renderer": "tilerender",
        "version": tracer_version(),
        "camera": camera.model_dump(),
        "render": settings.model_dump(),
        "effect_plan": effect_plan(scene, settings).to_json(),
        "seconds": round(seconds, 3),
    }
    for path in outputs:
        write_image(path, image, metadata)
    if not quiet:
        rate = samples_total / seconds / 1e6
        names = ", ".join(str(p) for p in outputs)
        stderr.print(
            f"wrote {names}: {camera.width}x{camera.height}, {settings.spp} spp, "
            f"{seconds:.2f} s, {rate:.2f} M samples/s"
        )
    return seconds


def tracer_version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("tilerender")
    except PackageNotFoundError:
        return "unknown"


def cmd_render(args: argparse.Namespace) -> int:
    output = check_output_path(args.output)
    if not output.parent.is_dir():
        raise UsageError(f"{output.parent}: output directory does not exist")
    scene = load(args.scene)
    camera, settings = settings_for(scene, args)
    render_to_file(
        scene, camera, settings, [output], args.threads, args.quiet, Path(args.scene).name
    )
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

"""Whole-renderer ray throughput per sample scene, as the Ray Accelerator paper measures it.

For every sample scene (``scenes/*``), the renderer's own path (``tracer.render.render_image``:
camera rays, traversal, shading, light sampling, Russian roulette and the frame buffer) renders
one frame on ``--threads`` threads, after a warm-up that compiles or loads the kernels. Reported
per scene: M samples/s and M rays/s (median and best of ``--repeats``), where the rays are every
traversal the kernel made (camera, continuation and shadow rays, as ``out_rays`` counts them),
and rays per sample. This is the single-ray kernel's row of issue #23's table: the stream and
packet kernels, once built, get their own columns beside it.
"""

import argparse
import time

from common import (
    REPO_ROOT,
    Series,
    console,
    machine_info,
    print_machine,
    print_table,
    usable_cores,
    write_results,
)


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        description="Whole-renderer M rays/s and M samples/s of every sample scene (shading, "
        "light sampling and frame buffer included). Writes bench/results/renderer_mrays.json.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    parser.add_argument("--width", type=int, default=256, help="frame width in pixels")
    parser.add_argument("--height", type=int, default=192, help="frame height in pixels")
    parser.add_argument("--spp", type=int, default=16, help="samples per pixel")
    parser.add_argument("--repeats", type=int, default=5, help="timed renders per scene")
    parser.add_argument("--threads", type=int, default=usable_cores(), help="render threads")
    parser.add_argument(
        "--scenes", nargs="*", help="names of scenes/ folders (default: every sample scene)"
    )
    args = parser.parse_args(argv)
    if min(args.width, args.height, args.spp, args.repeats, args.threads) < 1:
        parser.error("--width, --height, --spp, --repeats and --threads must be at least 1")
    return args


def measure(args: argparse.Namespace) -> dict[str, dict]:
    from cli.commands.samples import sample_scene_files
    from tracer.compiled.scene import compile_scene
    from tracer.render import render_pixels
    from tracer.scene.format import override
    from tracer.scene.loader import load_scene

    paths = {path.parent.name: path for path in sample_scene_files(REPO_ROOT / "scenes")}
    unknown = sorted(set(args.scenes or ()) - set(paths))
    if unknown:
        raise SystemExit(f"unknown scene(s) {', '.join(unknown)}; known: {', '.join(paths)}")
    results = {}
    for name, path in paths.items():
        if args.scenes and name not in args.scenes:
            continue
        scene = compile_scene(load_scene(path))
        camera = override(scene.camera, width=args.width, height=args.height)
        settings = override(scene.render, spp=args.spp)
        pixels = camera.width * camera.height

        def render(scene=scene, camera=camera, settings=settings, pixels=pixels):
            start = time.perf_counter()
            run = render_pixels(scene, 0, pixels, camera, settings, threads=args.threads)
            return time.perf_counter() - start, int(run.rays.sum())

        render()  # warm-up: compile or load the kernels
        samples = Series("samples", pixels * settings.spp)
        ray_counts = set()
        for _ in range(args.repeats):
            seconds, rays = render()
            samples.seconds.append(seconds)
            ray_counts.add(rays)
        if len(ray_counts) != 1:
            raise RuntimeError(f"{name}: the ray count changed between renders: {ray_counts}")
        rays = ray_counts.pop()
        traced = Series("rays", rays, samples.seconds)
        results[name] = {
            "integrator": settings.integrator,
            "triangles": scene.stats.triangles,
            "max_depth": settings.max_depth,
            "rays": rays,
            "rays_per_sample": rays / samples.work,
            "samples": samples.summary(1e6),
            "rays_per_second": traced.summary(1e6),
        }
        console.print(f"[dim]{name}: {traced.median_rate / 1e6:.2f} M rays/s[/]")
    return results


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    info = machine_info()
    print_machine(info)
    results = measure(args)
    rows = [
        (
            name,
            r["integrator"],
            f"{r['triangles']:,}",
            f"{r['rays_per_sample']:.2f}",
            f"{r['samples']['median_rate']:.3f}",
            f"{r['rays_per_second']['median_rate']:.2f}",
            f"{r['rays_per_second']['best_rate']:.2f}",
        )
        for name, r in results.items()
    ]
    print_table(
        f"Whole renderer, single-ray kernel, {args.width}x{args.height} at {args.spp} spp, "
        f"{args.threads} threads, {args.repeats} renders each",
        ["scene", "integrator", "triangles", "rays/sample", "M samples/s", "M rays/s", "best"],
        rows,
        caption="rays: every traversal (camera, continuation, shadow); medians unless 'best'",
    )
    write_results("renderer_mrays", {"options": vars(args), "scenes": results}, info)


if __name__ == "__main__":
    main()

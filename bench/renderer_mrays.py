"""Whole-renderer ray throughput per sample scene and kernel, as the Ray Accelerator paper
measures it (its Table 1 compares SINGLERAY, PACKET, SIMD and HYBRID renderers).

For every sample scene (``scenes/*``), the renderer's own path (``tracer.render.render_pixels``:
camera rays, traversal, shading, light sampling, Russian roulette and the frame buffer) renders
one frame on ``--threads`` threads with each of ``--kernels`` (``single``: a path at a time;
``stream``: a stream of paths a stage at a time), after a warm-up that compiles or loads the
kernels. In each round every kernel renders once, in turns, so they see the same machine load.
Reported per scene and kernel: M samples/s and M rays/s (median and best of ``--repeats``),
where the rays are every traversal the kernel made (camera, continuation and shadow rays, as
``out_rays`` counts them); the stream / single ratio (median of per-round ratios); which
kernel ``render.kernel: auto`` picks; and whether the kernels' images are bit-identical.
The renderer has no packet kernel (packets exist for ``closest_hits`` only: ``bench/packets.py``).
"""

import argparse
import statistics
import tempfile
import time
from pathlib import Path

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
    parser.add_argument(
        "--meshes",
        type=int,
        default=8,
        metavar="SUBDIVISIONS",
        help="also the Cornell box with bench/raycast.py's smooth and bumpy icospheres of this "
        "many subdivisions (8: 1.31M triangles) in place of its boxes; 0 for none",
    )
    parser.add_argument(
        "--kernels",
        nargs="+",
        choices=("single", "stream"),
        default=["single", "stream"],
        help="kernels to measure side by side",
    )
    args = parser.parse_args(argv)
    if min(args.width, args.height, args.spp, args.repeats, args.threads) < 1:
        parser.error("--width, --height, --spp, --repeats and --threads must be at least 1")
    return args


def mesh_scenes(subdivisions: int, folder: Path) -> dict[str, Path]:
    """Scene files of the Cornell box with ``raycast.icospheres``' meshes (radius 0.45, on the
    floor) instead of its two boxes, written under ``folder``: name -> scene file."""
    import json
    import shutil

    import numpy as np
    import trimesh
    from raycast import icospheres

    cornell = REPO_ROOT / "scenes" / "cornell-box"
    for obj in cornell.glob("*.obj"):
        shutil.copy(obj, folder / obj.name)
    base = json.loads((cornell / "scene.json").read_text())
    kept = [o for o in base["objects"] if o["name"] not in ("small-box", "large-box")]
    scenes = {}
    for mesh in icospheres(subdivisions, 0.02, 0):
        n = mesh.tri_verts.shape[0]
        faces = np.arange(3 * n).reshape(n, 3)
        shape = trimesh.Trimesh(mesh.tri_verts.reshape(-1, 3), faces, process=True)
        shape.export(folder / f"{mesh.name}.ply")
        sphere = {
            "name": mesh.name,
            "shape": f"{mesh.name}.ply",
            "material": "white",
            "transform": {"translate": [0.0, -0.55, 0.0], "scale": 0.45},
        }
        scene = folder / f"cornell-{mesh.name}-{n}.json"
        scene.write_text(json.dumps({**base, "objects": [*kept, sphere]}))
        scenes[f"cornell-{mesh.name}-sphere"] = scene
    return scenes


def measure(args: argparse.Namespace) -> dict[str, dict]:
    from cli.commands.samples import sample_scene_files
    from tracer.compiled.scene import compile_scene
    from tracer.integrators.kernel_choice import choose_kernel
    from tracer.render import render_pixels
    from tracer.scene.format import override
    from tracer.scene.loader import load_scene

    paths = {path.parent.name: path for path in sample_scene_files(REPO_ROOT / "scenes")}
    if args.meshes > 0:
        paths.update(mesh_scenes(args.meshes, Path(tempfile.mkdtemp(prefix="renderer-mrays-"))))
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
        auto = choose_kernel(settings).name

        def render(kernel, scene=scene, camera=camera, settings=settings, pixels=pixels):
            chosen = override(settings, kernel=kernel)
            start = time.perf_counter()
            run = render_pixels(scene, 0, pixels, camera, chosen, threads=args.threads)
            return time.perf_counter() - start, int(run.rays.sum()), run.rgb.tobytes()

        images = {kernel: render(kernel)[2] for kernel in args.kernels}  # warm-up
        samples = {k: Series("samples", pixels * settings.spp) for k in args.kernels}
        ray_counts = set()
        for round_ in range(args.repeats):
            order = args.kernels if round_ % 2 == 0 else args.kernels[::-1]
            for kernel in order:
                seconds, rays, _ = render(kernel)
                samples[kernel].seconds.append(seconds)
                ray_counts.add(rays)
        if len(ray_counts) != 1:
            raise RuntimeError(f"{name}: the ray count changed between renders: {ray_counts}")
        rays = ray_counts.pop()
        kernels = {}
        for kernel, series in samples.items():
            traced = Series("rays", rays, series.seconds)
            kernels[kernel] = {
                "samples": series.summary(1e6),
                "rays_per_second": traced.summary(1e6),
            }
        paired = None
        if {"single", "stream"} <= set(samples):
            per_round = [
                a / b
                for a, b in zip(samples["single"].seconds, samples["stream"].seconds, strict=True)
            ]
            paired = statistics.median(per_round)
        results[name] = {
            "integrator": settings.integrator,
            "triangles": scene.stats.triangles,
            "max_depth": settings.max_depth,
            "rays": rays,
            "rays_per_sample": rays / (pixels * settings.spp),
            "kernels": kernels,
            "stream_over_single": paired,
            "auto": auto,
            "bit_identical": len(set(images.values())) == 1,
        }
        rates = ", ".join(
            f"{k} {v['rays_per_second']['median_rate']:.2f}" for k, v in kernels.items()
        )
        console.print(f"[dim]{name}: {rates} M rays/s[/]")
    return results


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    info = machine_info()
    print_machine(info)
    results = measure(args)
    rows = []
    for name, r in results.items():
        rates = [f"{r['kernels'][k]['rays_per_second']['median_rate']:.2f}" for k in args.kernels]
        ratio = r["stream_over_single"]
        rows.append(
            (
                name,
                r["integrator"],
                f"{r['triangles']:,}",
                f"{r['rays_per_sample']:.2f}",
                *rates,
                "-" if ratio is None else f"{ratio:.2f}x",
                r["auto"],
                "yes" if r["bit_identical"] else "NO",
            )
        )
    print_table(
        f"Whole renderer, {args.width}x{args.height} at {args.spp} spp, {args.threads} threads, "
        f"{args.repeats} rounds",
        [
            "scene",
            "integrator",
            "triangles",
            "rays/sample",
            *(f"{k} M rays/s" for k in args.kernels),
            "stream/single",
            "auto",
            "same bits",
        ],
        rows,
        caption="rays: every traversal (camera, continuation, shadow); medians; the ratio is "
        "the median of per-round ratios",
    )
    write_results("renderer_mrays", {"options": vars(args), "scenes": results}, info)


if __name__ == "__main__":
    main()

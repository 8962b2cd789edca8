"""Packet traversal against single rays: closest hits of the ray-casting benchmark's meshes and
rays (``bench/raycast.py``: a smooth and a bumpy icosphere, camera rays in scanline order and
one diffuse bounce from each hit), both ways in this process, one thread, interleaved rounds,
thread CPU time. Reports M rays/s each way, the speed-up, the work (node visits plus triangle
tests) and whether every hit is bit-identical.
"""

import argparse
import statistics
import time

import numpy as np
from common import console, machine_info, print_machine, print_table, write_results
from raycast import camera_rays, diffuse_rays, icospheres

from tracer.geometry import bvh
from tracer.geometry.raycast import Hits, closest_hits


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        description="Closest hits by 4-ray packets against single rays (same hits, bit for "
        "bit); one thread. Writes bench/results/packets.json.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    parser.add_argument(
        "--subdivisions", type=int, nargs="+", default=[5, 8], help="icosphere subdivisions"
    )
    parser.add_argument("--rays", type=int, default=300_000, help="camera rays per mesh")
    parser.add_argument("--repeats", type=int, default=5, help="timed rounds")
    parser.add_argument("--noise", type=float, default=0.02, help="radial noise of 'bumpy'")
    parser.add_argument("--seed", type=int, default=1, help="seed of the noise and the rays")
    args = parser.parse_args(argv)
    if args.rays < 1 or args.repeats < 1 or min(args.subdivisions) < 0:
        parser.error("--rays and --repeats must be at least 1, --subdivisions at least 0")
    return args


def identical(a: Hits, b: Hits) -> bool:
    return all(np.array_equal(getattr(a, f), getattr(b, f)) for f in ("prim", "t", "b", "tri"))


def measure(trav: bvh.TraversalBVH, origins, directions, repeats: int) -> dict:
    def run(packets: bool) -> tuple[float, Hits]:
        start = time.thread_time()
        hits = closest_hits(trav, origins, directions, threads=1, packets=packets)
        return time.thread_time() - start, hits

    _, single = run(False)  # warm-up, and the hits to compare
    _, packed = run(True)
    seconds = {"single": [], "packet": []}
    for _ in range(repeats):
        seconds["single"].append(run(False)[0])
        seconds["packet"].append(run(True)[0])
    n = origins.shape[0]
    rates = {k: n / statistics.median(v) / 1e6 for k, v in seconds.items()}
    return {
        "rays": n,
        "seconds": seconds,
        "single_mrays": rates["single"],
        "packet_mrays": rates["packet"],
        "speedup": rates["packet"] / rates["single"],
        "work_single": int(single.cost.sum()),
        "work_packet": int(packed.cost.sum()),
        "identical": identical(single, packed),
    }


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    info = machine_info()
    print_machine(info)
    results = {}
    for subdivisions in args.subdivisions:
        for mesh in icospheres(subdivisions, args.noise, args.seed):
            trav = bvh.to_traversal(bvh.build(mesh.tri_verts), mesh.tri_verts)
            rng = np.random.default_rng(args.seed)
            camera = camera_rays(args.rays, rng)
            hits = closest_hits(trav, camera.origins, camera.directions, threads=1)
            diffuse = diffuse_rays(mesh, camera, hits, rng)
            for rays in (camera, diffuse):
                name = f"{mesh.name} {mesh.triangles:,} / {rays.name}"
                results[name] = measure(trav, rays.origins, rays.directions, args.repeats)
                console.print(f"[dim]{name}: {results[name]['speedup']:.2f}x[/]")
    rows = [
        (
            name,
            f"{r['single_mrays']:.3f}",
            f"{r['packet_mrays']:.3f}",
            f"{r['speedup']:.2f}",
            f"{r['work_single']:,} / {r['work_packet']:,}",
            "yes" if r["identical"] else "NO",
        )
        for name, r in results.items()
    ]
    print_table(
        f"Closest hits, one thread, {args.repeats} rounds: single rays vs 4-ray packets",
        ["mesh / rays", "single Mrays/s", "packet Mrays/s", "speed-up", "work", "identical"],
        rows,
        caption="medians of thread CPU time; work: node visits + triangle tests (single / packet)",
    )
    write_results("packets", {"options": vars(args), "results": results}, info)


if __name__ == "__main__":
    main()

"""What a light-tree sample costs beside a power sample (issue #26): the same frame rendered with
each sampler, interleaved, on one thread, and the tree's picks alone.

A frame (``--width`` x ``--height``, ``--spp`` samples) of the scene with
``render.light_sampler`` ``power`` and ``tree`` in turns, ``--repeats`` rounds after a warm
one: seconds per sample-pixel each, and tree / power (median of the per-round ratios). Then
``--picks`` tree picks from points on the floor of the scene's box (normal up), timed in one
jitted loop: microseconds per pick, and the tree's depth.
"""

import argparse
import statistics

import numpy as np
from common import (
    REPO_ROOT,
    Contender,
    interleaved,
    machine_info,
    print_machine,
    print_table,
    time_call,
    write_results,
)
from numba import njit

from tracer.compiled.light_tree import light_tree_of
from tracer.compiled.scene import compile_scene
from tracer.render import render_pixels
from tracer.scene import format as fmt
from tracer.scene.loader import load_scene
from tracer.shading.light_tree import tree_sample


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0],
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    parser.add_argument("--scene", default=str(REPO_ROOT / "scenes" / "lamp-hall" / "scene.json"))
    parser.add_argument("--width", type=int, default=120)
    parser.add_argument("--height", type=int, default=80)
    parser.add_argument("--spp", type=int, default=8)
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--picks", type=int, default=200_000)
    args = parser.parse_args(argv)
    if min(args.width, args.height, args.spp, args.repeats, args.picks) < 1:
        parser.error("sizes, --spp, --repeats and --picks must be at least 1")
    return args


@njit(cache=True)
def _picks(nodes, child, points, u):
    total = 0.0
    for i in range(points.shape[0]):
        p = (points[i, 0], points[i, 1], points[i, 2])
        _, pmf = tree_sample(nodes, child, p, (0.0, 1.0, 0.0), u[i])
        total += pmf
    return total


def _depths(child, bits) -> list[int]:
    depths = []
    for trail in bits:
        trail, node, depth = int(trail), 0, 1
        while child[node, trail & 3] >= 0:
            node, trail, depth = int(child[node, trail & 3]), trail >> 2, depth + 1
        depths.append(depth)
    return depths


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    info = machine_info()
    print_machine(info)
    scene = compile_scene(load_scene(args.scene))
    camera = fmt.override(scene.camera, width=args.width, height=args.height)
    pixels = args.width * args.height
    contenders = {}
    for sampler in ("power", "tree"):
        settings = fmt.override(scene.render, spp=args.spp, light_sampler=sampler)
        contenders[sampler] = Contender(
            lambda _, s=settings: render_pixels(scene, 0, pixels, camera, s, threads=1)
        )
        contenders[sampler].run(0)  # warm: kernel and tree
    work = {name: pixels * args.spp for name in contenders}
    series = interleaved(contenders, work, args.repeats)
    power, tree = series["power"], series["tree"]
    per_round = [t / p for t, p in zip(tree.seconds, power.seconds, strict=True)]
    ratio = statistics.median(per_round)
    print_table(
        f"{args.scene}: one thread, {args.width}x{args.height}, {args.spp} spp",
        ["sampler", "median s", "best s", "us per sample"],
        [
            [
                s.name,
                f"{s.median_seconds:.3f}",
                f"{s.best_seconds:.3f}",
                f"{1e6 * s.median_seconds / s.work:.2f}",
            ]
            for s in (power, tree)
        ],
        caption=f"a tree sample costs {ratio:.2f}x a power sample (median of per-round ratios)",
    )
    arrays = light_tree_of(scene)
    rng = np.random.default_rng(1)
    lo = np.array(scene.stats.bounds_min) - scene.origin
    hi = np.array(scene.stats.bounds_max) - scene.origin
    points = lo + (hi - lo) * rng.random((args.picks, 3))
    points[:, 1] = lo[1] + 1e-3 * (hi[1] - lo[1])
    u = rng.random(args.picks)
    nodes, child = arrays.light_tree_nodes, arrays.light_tree_child
    _picks(nodes, child, points[:10], u[:10])
    seconds = [time_call(lambda: _picks(nodes, child, points, u))[0] for _ in range(args.repeats)]
    pick_us = 1e6 * statistics.median(seconds) / args.picks
    depths = _depths(child, arrays.light_tree_bits)
    print(
        f"{len(depths)} lights, {child.shape[0]} nodes, depth mean {np.mean(depths):.2f} "
        f"max {max(depths)}; {pick_us:.3f} us per pick (median of {args.repeats})"
    )
    payload = {
        "scene": args.scene,
        "power": power.summary(),
        "tree": tree.summary(),
        "tree_over_power_per_sample": ratio,
        "pick_us": pick_us,
        "depth_mean": float(np.mean(depths)),
        "depth_max": max(depths),
    }
    write_results("light_tree_cost", payload, info)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

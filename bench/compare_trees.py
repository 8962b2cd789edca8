"""One scene rendered by two source trees side by side: what a change costs.

Each tree gets a long-lived worker process (``PYTHONPATH`` set to the tree, its own kernel
cache) that loads and compiles the scene and renders it once to warm up. Then, for
``--repeats`` rounds, the script asks each worker for one timed render, alternating which goes
first, so both see the same machine load. Reported: median and best seconds per tree, the
throughput ratio this tree / base (of the medians, of the bests, and the median of per-round
ratios), and whether the two trees' images are bit-identical.

Get a base tree without touching a working tree, e.g.::

    git archive main | tar -x -C /tmp/base-tree
    python bench/compare_trees.py --base /tmp/base-tree --scene scenes/cornell-box/scene.json
"""

import argparse
import tempfile
from pathlib import Path

from common import (
    REPO_ROOT,
    Series,
    TreeWorker,
    console,
    fmt_float,
    machine_info,
    print_machine,
    print_table,
    ratios,
    usable_cores,
    write_results,
)

WORKER = """
import hashlib, json, sys, time
from tracer.render import render_image
try:
    from tracer.compiled.scene import compile_scene
    from tracer.scene import format as fmt
    from tracer.scene.loader import load_scene
except ImportError:  # a base tree from before tracer/ had subpackages (issue #21)
    from tracer.compile import compile_scene
    from tracer import scene_format as fmt
    from tracer.loader import load_scene

scene_path, width, height, spp, threads = sys.argv[1:6]
scene = compile_scene(load_scene(scene_path))
camera = fmt.override(scene.camera, width=int(width), height=int(height))
settings = fmt.override(scene.render, spp=int(spp))

def render():
    start = time.perf_counter()
    image, _ = render_image(scene, camera, settings, threads=int(threads))
    return time.perf_counter() - start, hashlib.sha256(image.tobytes()).hexdigest()

render()
print(json.dumps({"ready": True}), flush=True)
for _ in sys.stdin:
    seconds, digest = render()
    print(json.dumps({"seconds": seconds, "sha256": digest}), flush=True)
"""


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        description="Render one scene with this tree and a base tree, interleaved in warm "
        "worker processes; throughput ratio and bit-identity. Writes "
        "bench/results/compare_trees.json.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    parser.add_argument("--base", required=True, help="the other source tree (a checkout)")
    parser.add_argument("--tree", default=str(REPO_ROOT), help="this source tree")
    parser.add_argument("--scene", default=str(REPO_ROOT / "scenes" / "cornell-box" / "scene.json"))
    parser.add_argument("--width", type=int, default=256)
    parser.add_argument("--height", type=int, default=192)
    parser.add_argument("--spp", type=int, default=16)
    parser.add_argument("--repeats", type=int, default=9, help="timed rounds")
    parser.add_argument("--threads", type=int, default=usable_cores())
    parser.add_argument(
        "--tree-cache", help="kernel cache for this tree, kept between runs (default: a fresh one)"
    )
    parser.add_argument(
        "--base-cache", help="kernel cache for the base tree, kept between runs (default: fresh)"
    )
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    info = machine_info()
    print_machine(info)
    work = args.width * args.height * args.spp
    series = {"tree": Series("tree", work), "base": Series("base", work)}
    digests = {"tree": set(), "base": set()}
    with tempfile.TemporaryDirectory() as tree_cache, tempfile.TemporaryDirectory() as base_cache:
        worker_args = [args.scene, str(args.width), str(args.height), str(args.spp),
                       str(args.threads)]  # fmt: skip
        tree_cache = args.tree_cache or tree_cache
        base_cache = args.base_cache or base_cache
        workers = {"tree": TreeWorker(WORKER, worker_args, args.tree, tree_cache)}
        workers["base"] = TreeWorker(WORKER, worker_args, args.base, base_cache)
        try:
            for round_index in range(args.repeats):
                order = ["tree", "base"] if round_index % 2 == 0 else ["base", "tree"]
                for name in order:
                    result = workers[name].ask("go")
                    series[name].seconds.append(result["seconds"])
                    digests[name].add(result["sha256"])
        finally:
            for worker in workers.values():
                worker.close()
    ratio = ratios(series["tree"], series["base"])
    identical = digests["tree"] == digests["base"] and len(digests["tree"]) == 1
    rows = [
        (name, fmt_float(s.median_seconds, 3), fmt_float(s.best_seconds, 3))
        for name, s in series.items()
    ]
    print_table(
        f"{Path(args.scene).parent.name}, {args.width}x{args.height}, {args.spp} spp, "
        f"{args.threads} threads, {args.repeats} rounds",
        ["tree", "median s", "best s"],
        rows,
        caption=f"throughput tree/base: median {ratio['median']:.3f}, best {ratio['best']:.3f}, "
        f"paired {ratio['paired_median']:.3f}; images bit-identical: "
        f"{'yes' if identical else 'no'}",
    )
    write_results(
        "compare_trees",
        {
            "options": vars(args),
            "series": {name: s.summary() for name, s in series.items()},
            "ratio": ratio,
            "bit_identical": identical,
        },
        info,
    )
    console.print(f"bit-identical: {identical}")


if __name__ == "__main__":
    main()

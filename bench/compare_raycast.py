"""Ray casting by two source trees side by side: what a traversal change gains.

The meshes and rays of ``bench/raycast.py`` (smooth and bumpy icospheres; camera rays and one
diffuse bounce from each hit), made once by this tree and saved to a temporary file. Each tree
gets a long-lived worker process (``PYTHONPATH`` set to the tree, its own kernel cache) that
builds its BVHs and warms up; then, for ``--repeats`` rounds, each worker casts every ray set on
one thread (closest hits, and any hits with ``t_max`` half the closest distance), alternating
which goes first. Times are the worker thread's CPU time, which other processes on a shared
machine disturb far less than wall time. Reported per ray set: Mrays/s of both trees, the
speed-up tree/base (ratio of medians and median of per-round ratios, with its range), whether
the answers are bit-identical, and the work counters (node visits plus triangle tests).

    python bench/compare_raycast.py --base /tmp/base-tree --subdivisions 7 --rays 200000
"""

import argparse
import tempfile
from pathlib import Path

import numpy as np
from common import (
    REPO_ROOT,
    Series,
    TreeWorker,
    fmt_float,
    machine_info,
    print_machine,
    print_table,
    ratios,
    write_results,
)
from raycast import camera_rays, diffuse_rays, icospheres

from tracer.geometry import bvh
from tracer.geometry.raycast import closest_hits

WORKER = """
import hashlib, json, sys, time
import numpy as np
from tracer.geometry import bvh
from tracer.geometry.raycast import any_hits, closest_hits

data = np.load(sys.argv[1])
names = [str(n) for n in data["names"]]
trees = {}
for mesh in names:
    tv = data[f"{mesh}/verts"]
    trees[mesh] = bvh.to_traversal(bvh.build(tv), tv)
    closest_hits(trees[mesh], data[f"{mesh}/camera/o"][:100], data[f"{mesh}/camera/d"][:100], 1)
    any_hits(trees[mesh], data[f"{mesh}/camera/o"][:100], data[f"{mesh}/camera/d"][:100], 1.0, 1)
print(json.dumps({"ready": True}), flush=True)
for line in sys.stdin:
    mesh, rays, query = line.split()
    o, d = data[f"{mesh}/{rays}/o"], data[f"{mesh}/{rays}/d"]
    start = time.thread_time()
    if query == "closest":
        h = closest_hits(trees[mesh], o, d, threads=1)
        seconds = time.thread_time() - start
        digest = hashlib.sha256(h.prim.tobytes() + h.t.tobytes() + h.b.tobytes()).hexdigest()
        work = int(h.cost.sum())
    else:
        hit = any_hits(trees[mesh], o, d, data[f"{mesh}/{rays}/half"], threads=1)
        seconds = time.thread_time() - start
        digest, work = hashlib.sha256(hit.tobytes()).hexdigest(), 0
    print(json.dumps({"seconds": seconds, "sha256": digest, "work": work}), flush=True)
"""


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        description="Ray casting (bench/raycast.py's meshes and rays) by this tree and a base "
        "tree, interleaved in warm worker processes, one thread, CPU time: speed-up and "
        "bit-identity. Writes bench/results/compare_raycast.json.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    parser.add_argument("--base", required=True, help="the other source tree (a checkout)")
    parser.add_argument("--tree", default=str(REPO_ROOT), help="this source tree")
    parser.add_argument("--subdivisions", type=int, default=8, help="icosphere subdivisions")
    parser.add_argument("--rays", type=int, default=300_000, help="camera rays per mesh")
    parser.add_argument("--repeats", type=int, default=7, help="timed rounds")
    parser.add_argument("--seed", type=int, default=1)
    return parser.parse_args(argv)


def make_rays(args: argparse.Namespace, path: Path) -> dict[str, int]:
    """Save meshes and ray sets to ``path``; returns the number of rays of each set."""
    arrays, counts = {}, {}
    for mesh in icospheres(args.subdivisions, 0.02, args.seed):
        rng = np.random.default_rng(args.seed)
        trav = bvh.to_traversal(bvh.build(mesh.tri_verts), mesh.tri_verts)
        camera = camera_rays(args.rays, rng)
        hits = closest_hits(trav, camera.origins, camera.directions)
        diffuse = diffuse_rays(mesh, camera, hits, rng)
        arrays[f"{mesh.name}/verts"] = mesh.tri_verts
        for rays in (camera, diffuse):
            t = closest_hits(trav, rays.origins, rays.directions).t
            arrays[f"{mesh.name}/{rays.name}/o"] = rays.origins
            arrays[f"{mesh.name}/{rays.name}/d"] = rays.directions
            arrays[f"{mesh.name}/{rays.name}/half"] = np.where(np.isfinite(t), 0.5 * t, 1e30)
            counts[f"{mesh.name}/{rays.name}"] = rays.count
    arrays["names"] = np.array(["smooth", "bumpy"])
    np.savez(path, **arrays)
    return counts


HEADERS = [
    "mesh/rays query",
    "base Mrays/s",
    "tree Mrays/s",
    "speed-up",
    "paired (range)",
    "identical",
    "work base / tree",
]


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    info = machine_info()
    print_machine(info)
    rows, records = [], {}
    with tempfile.TemporaryDirectory() as work:
        data = Path(work) / "rays.npz"
        counts = make_rays(args, data)
        workers = {
            "tree": TreeWorker(WORKER, [str(data)], args.tree, str(Path(work) / "tree-cache")),
            "base": TreeWorker(WORKER, [str(data)], args.base, str(Path(work) / "base-cache")),
        }
        try:
            for key, count in counts.items():
                for query in ("closest", "any"):
                    series = {name: Series(name, count) for name in workers}
                    digests = {name: set() for name in workers}
                    work_done = {}
                    for round_index in range(args.repeats):
                        order = ["tree", "base"] if round_index % 2 == 0 else ["base", "tree"]
                        for name in order:
                            result = workers[name].ask(f"{key.replace('/', ' ')} {query}")
                            series[name].seconds.append(result["seconds"])
                            digests[name].add(result["sha256"])
                            work_done[name] = result["work"]
                    ratio = ratios(series["tree"], series["base"])
                    per_round = [
                        b / t
                        for t, b in zip(series["tree"].seconds, series["base"].seconds, strict=True)
                    ]
                    identical = digests["tree"] == digests["base"] and len(digests["tree"]) == 1
                    paired = (
                        f"{ratio['paired_median']:.3f} ({min(per_round):.3f}-{max(per_round):.3f})"
                    )
                    work_text = (
                        f"{work_done['base']:,} / {work_done['tree']:,}"
                        if work_done["base"]
                        else ""
                    )
                    rows.append(
                        (
                            f"{key} {query}",
                            fmt_float(count / series["base"].median_seconds / 1e6, 3),
                            fmt_float(count / series["tree"].median_seconds / 1e6, 3),
                            fmt_float(ratio["median"], 3),
                            paired,
                            "yes" if identical else "NO",
                            work_text,
                        )
                    )
                    records[f"{key}/{query}"] = {
                        "series": {name: s.summary() for name, s in series.items()},
                        "ratio": ratio,
                        "bit_identical": identical,
                        "work": work_done,
                    }
        finally:
            for worker in workers.values():
                worker.close()
    print_table(
        f"Ray casting, one thread, {args.repeats} rounds: base {args.base} vs tree {args.tree}",
        HEADERS,
        rows,
        caption="Mrays/s from the median of the worker thread's CPU seconds; speed-up tree/base",
    )
    write_results("compare_raycast", {"options": vars(args), "sets": records}, info)


if __name__ == "__main__":
    main()

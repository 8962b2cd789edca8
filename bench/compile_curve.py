"""How the steps of an upload grow with the scene: N separate objects (one node each) of a
built-in shape, N up to 200,000.

``curve`` (the default) times, in this process, every step a JSON upload goes through for N
boxes (12 triangles each) on a grid: ``load`` (JSON parse, scene model, the state),
``check`` (``check_state``, as the scene graph does), ``bounds`` (the summary's world bounds),
``compile`` (``compile_scene``: static clusters, the baked meshes, their BVHs, the top level,
lights), ``bvh`` (the baked mesh's BVH rebuilt alone, part of ``compile``), ``plan`` (the
effect plan) and ``encode`` / ``decode`` (the snapshot the tracers are sent). Per step: CPU
seconds of this process (which a shared machine inflates far less than wall-clock seconds;
both are kept), the least-squares constant in seconds per node, and t(2N)/t(N) between
consecutive sizes (2.0 is linear). Writes ``bench/results/compile_curve.{json,csv,png}``
(``--docs``: the CSV and the plot into ``docs/performance/``).

``service`` uploads N rectangles (2 triangles each: 200,000 nodes are 400,000 triangles, under
the service's 2M limit) to a ``tilerender serve`` on 127.0.0.1 with its own Ray, then
inspects the scene and renders its first frame as a job; reports each request's status and
seconds. ``--request-timeout`` is passed to the server (its default is 30 s)::

    python bench/compile_curve.py                        # 1,562 to 200,000 boxes
    python bench/compile_curve.py --sizes 1000 2000 4000 # a quick check
    python bench/compile_curve.py service --nodes 200000
"""

import argparse
import csv
import gc
import json
import math
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

from common import (
    REPO_ROOT,
    RESULTS_DIR,
    console,
    fmt_float,
    machine_info,
    note,
    print_machine,
    print_table,
    pyplot,
    write_results,
)

STEPS = ("load", "check", "bounds", "compile", "bvh", "plan", "encode", "decode")
DEFAULT_SIZES = [1562, 3125, 6250, 12500, 25000, 50000, 100000, 200000]
DOCS_DIR = REPO_ROOT / "docs" / "performance"


def grid_scene(nodes: int, shape: str, width: int = 64, height: int = 48) -> dict:
    """A scene of ``nodes`` objects of ``shape`` (boxes of side 2, three units apart, or 2 x 2
    rectangles facing the camera, two apart) on a square grid in the xz plane, under a constant
    sky. Written compactly, 200,000 of either stay under the loader's 16 MiB scene file limit
    (a box with an explicit size would not)."""
    side = math.ceil(math.sqrt(nodes))
    step = 3 if shape == "box" else 2
    objects = [
        {"shape": {"type": shape}, "material": "m",
         "transform": {"translate": [step * (i % side), 0, step * (i // side)]}}
        for i in range(nodes)
    ]  # fmt: skip
    middle = side * step / 2
    return {
        "camera": {"position": [middle, middle, -0.5 * side], "look_at": [middle, 0, middle],
                   "width": width, "height": height},
        "render": {"spp": 1, "max_depth": 2},
        "materials": {"m": {"type": "diffuse", "reflectance": [0.6, 0.6, 0.6]}},
        "sky": {"type": "constant", "radiance": [1, 1, 1]},
        "objects": objects,
    }  # fmt: skip


def timed(fn: Callable[[], object]) -> tuple[float, float, object]:
    """CPU and wall-clock seconds of one call of ``fn``, and its result."""
    gc.collect()
    cpu, wall = time.process_time(), time.perf_counter()
    result = fn()
    return time.process_time() - cpu, time.perf_counter() - wall, result


def measure(nodes: int, shape: str, workdir: Path) -> dict:
    """Every step for one scene size: ``{step: (cpu, wall)}`` plus the scene's figures."""
    from api.scenes import bounds
    from tracer.compiled.scene import STATIC_KEY, compile_scene
    from tracer.geometry import bvh
    from tracer.integrators.effects import effect_plan
    from tracer.scene.checks import check_state
    from tracer.scene.codec import decode_state, encode_state
    from tracer.scene.loader import load_scene

    path = workdir / f"scene-{nodes}.json"
    path.write_text(json.dumps(grid_scene(nodes, shape), separators=(",", ":")))
    row: dict = {"nodes": nodes, "file_bytes": path.stat().st_size}
    out: dict = {}

    def step(name, fn):
        cpu, wall, result = timed(fn)
        out[name] = (cpu, wall)
        return result

    state = step("load", lambda: load_scene(path))
    step("check", lambda: check_state(state))
    step("bounds", lambda: bounds(state))
    compiled = step("compile", lambda: compile_scene(state))
    baked = compiled.meshes[STATIC_KEY].bvh.tri_verts
    step("bvh", lambda: bvh.to_traversal(bvh.build(baked, None), baked))
    step("plan", lambda: effect_plan(compiled, state.render))
    blob = step("encode", lambda: encode_state(state))
    step("decode", lambda: decode_state(blob))
    row.update(triangles=compiled.stats.triangles, static_clusters=compiled.static_clusters)
    row["steps"] = out
    path.unlink()
    return row


def fit(rows: list[dict], step: str, index: int = 0) -> dict:
    """Seconds per node (least squares through the origin) of ``step`` and t(2N)/t(N) between
    consecutive sizes, each scaled to a doubling: (t_b / t_a) ** (1 / log2(N_b / N_a)) * 2."""
    n = [r["nodes"] for r in rows]
    t = [r["steps"][step][index] for r in rows]
    per_node = sum(a * b for a, b in zip(n, t, strict=True)) / sum(a * a for a in n)
    doubling = []
    for k in range(1, len(n)):
        (na, ta), (nb, tb) = (n[k - 1], t[k - 1]), (n[k], t[k])
        doubling.append(None if ta <= 0 else 2 ** (math.log2(tb / ta) / math.log2(nb / na)))
    return {"seconds_per_node": per_node, "doubling": doubling}


def plot(rows: list[dict], fits: dict, path: Path, title: str) -> None:
    plt = pyplot()
    if plt is None:
        return
    fig, ax = plt.subplots(figsize=(8, 4.8), dpi=110)
    n = [r["nodes"] for r in rows]
    for step in STEPS:
        if step == "bvh":
            continue  # part of compile
        seconds = [max(r["steps"][step][0], 1e-5) for r in rows]
        us = 1e6 * fits[step]["seconds_per_node"]
        ax.plot(n, seconds, marker="o", markersize=3, label=f"{step}: {us:.1f} us/node")
    ax.plot(n, [sum(r["steps"][s][0] for s in STEPS if s != "bvh") for r in rows], color="black",
            linewidth=2, label="all steps")  # fmt: skip
    guide = [rows[-1]["steps"]["load"][0] * x / n[-1] for x in n]
    ax.plot(n, guide, color="grey", linestyle=":", linewidth=1, label="linear (through load)")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("nodes (one object each)")
    ax.set_ylabel("CPU seconds")
    ax.set_title(title, fontsize=10)
    ax.legend(loc="upper left", fontsize=7)
    ax.grid(alpha=0.3, which="both")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def write_csv(rows: list[dict], path: Path) -> None:
    with open(path, "w", newline="") as f:
        writer = csv.writer(f)
        header = ["nodes", "triangles", "file_bytes", "static_clusters"]
        header += [f"{s}_cpu_s" for s in STEPS] + [f"{s}_wall_s" for s in STEPS]
        writer.writerow(header)
        for r in rows:
            cells = [r["nodes"], r["triangles"], r["file_bytes"], r["static_clusters"]]
            cells += [f"{r['steps'][s][0]:.4f}" for s in STEPS]
            cells += [f"{r['steps'][s][1]:.4f}" for s in STEPS]
            writer.writerow(cells)


def curve(args) -> int:
    machine = machine_info()
    print_machine(machine)
    rows = []
    with tempfile.TemporaryDirectory(prefix="tilerender-curve-") as tmp:
        measure(200, args.shape, Path(tmp))  # compiles or loads the kernels
        for nodes in args.sizes:
            row = measure(nodes, args.shape, Path(tmp))
            rows.append(row)
            cells = " ".join(f"{s} {row['steps'][s][0]:.2f}" for s in STEPS)
            console.print(f"[dim]{nodes} nodes: {cells} (CPU s)[/]")
    fits = {step: fit(rows, step) for step in STEPS}
    columns = ["step", "us/node (CPU)", "at the largest N (CPU s)", "wall s", "t(2N)/t(N)"]
    table = []
    for step in STEPS:
        doubling = " ".join(fmt_float(d) for d in fits[step]["doubling"])
        last = rows[-1]["steps"][step]
        table.append([step, f"{1e6 * fits[step]['seconds_per_node']:.2f}", f"{last[0]:.2f}",
                      f"{last[1]:.2f}", doubling])  # fmt: skip
    print_table(
        f"upload steps, {args.shape} nodes {args.sizes[0]}-{args.sizes[-1]}", columns, table
    )
    out = DOCS_DIR if args.docs else RESULTS_DIR
    out.mkdir(parents=True, exist_ok=True)
    write_csv(rows, out / "compile_curve.csv")
    plot(rows, fits, out / "compile_curve.png", f"CPU seconds per upload step, N {args.shape}es")
    write_results("compile_curve", {"shape": args.shape, "rows": rows, "fits": fits}, machine)
    return 0


def service(args) -> int:
    import httpx

    from bench.load.topology import serve_embedded

    machine = machine_info()
    print_machine(machine)
    report: dict = {"nodes": args.nodes, "request_timeout": args.request_timeout}
    with tempfile.TemporaryDirectory(prefix="tilerender-curve-service-") as tmp:
        work = Path(tmp)
        body = json.dumps(grid_scene(args.nodes, "rectangle"), separators=(",", ":")).encode()
        report["file_bytes"] = len(body)
        extra = ["--tracers", "1", "--threads", "1"]
        api = serve_embedded(
            work,
            work / "data",
            *extra,
            env={"TILERENDER_REQUEST_TIMEOUT": str(args.request_timeout)},
        )
        try:
            http = httpx.Client(base_url=api.url, timeout=args.request_timeout + 600)

            def request(name, method, url, **kwargs):
                start = time.perf_counter()
                r = http.request(method, url, **kwargs)
                seconds = time.perf_counter() - start
                report[name] = {"status": r.status_code, "seconds": round(seconds, 3)}
                if r.status_code >= 400:
                    report[name]["error"] = r.text[:300]
                console.print(f"{name}: {r.status_code} in {seconds:.2f} s")
                return r

            r = request("upload", "POST", "/v1/scenes", content=body,
                        headers={"content-type": "application/json"})  # fmt: skip
            if r.status_code == 201:
                scene = r.json()
                report["triangles"] = scene["triangles"]
                request("inspect", "GET", f"/v1/scenes/{scene['id']}")
                request("list", "GET", "/v1/scenes")
                job = request("submit", "POST", "/v1/jobs", json={"scene_id": scene["id"],
                              "spp": 1, "width": 64, "height": 48})  # fmt: skip
                if job.status_code == 202:
                    start = time.perf_counter()
                    status = None
                    while time.perf_counter() - start < args.frame_timeout:
                        status = http.get(f"/v1/jobs/{job.json()['id']}").json()["status"]
                        if status in ("done", "failed", "cancelled"):
                            break
                        time.sleep(0.25)
                    seconds = round(time.perf_counter() - start, 3)
                    report["first_frame"] = {"status": status, "seconds": seconds}
                    console.print(f"first frame: {status} after {seconds:.2f} s")
        finally:
            api.stop()
            report["log_tail"] = api.log_tail(1500)
    write_results("compile_curve_service", report, machine)
    ok = report.get("first_frame", {}).get("status") == "done"
    if not ok:
        note(
            "the scene did not reach its first frame: see bench/results/compile_curve_service.json"
        )
    return 0 if ok else 1


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("mode", nargs="?", choices=("curve", "service"), default="curve")
    parser.add_argument("--sizes", type=int, nargs="+", default=DEFAULT_SIZES)
    parser.add_argument("--shape", choices=("box", "rectangle"), default="box")
    parser.add_argument("--docs", action="store_true", help="CSV and plot into docs/performance/")
    parser.add_argument("--nodes", type=int, default=200_000, help="service mode: rectangles")
    parser.add_argument("--request-timeout", type=float, default=30.0)
    parser.add_argument("--frame-timeout", type=float, default=600.0)
    args = parser.parse_args(argv)
    return curve(args) if args.mode == "curve" else service(args)


if __name__ == "__main__":
    sys.exit(main())

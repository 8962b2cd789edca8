"""The cluster on this machine: scaling, coordination overhead, idle time per balancer with
real tracers (Bikker's Table 16), and recovery from a killed tracer.

1. **Scaling**: the Cornell box at 512x512, 16 spp, rendered by three set-ups that coexist on
   one embedded Ray and take turns, round by round: one tracer of one CPU, two tracers of one
   CPU each, one tracer using both CPUs through its threads. Targets: two tracers >= 1.8x one,
   and within 10% of one tracer with two threads.
2. **Overhead**: the same at 256x256: wall time minus the slowest tracer's busy time
   (scheduling, transfer, assembly), as a share of the frame. Target <= 5%.
3. **Idle time, real tracers**: 128 frames of an orbiting camera around the uneven scene of
   ``record_cost_traces`` (busts below the horizon, sky above), slow and fast orbit, two tracers
   of one CPU each, every balancer; mean idle % (Table 16's measure) over the frames.
4. **Recovery**: a tracer killed in the middle of a frame; time from the kill to the frame's
   completion, against the same frame without a failure.
5. **Calls**: what a render call costs a tracer outside rendering (round trip, and the gap
   between calls queued back to back): the dynamic tail pays it per chunk, and the simulator's
   ``--latency-ms`` / ``--call-gap-ms`` come from it.
"""

import argparse
import itertools
import os
import signal
import statistics
import sys
import threading
import time
from pathlib import Path

import numpy as np
import ray

sys.path.insert(0, str(Path(__file__).resolve().parent))  # for `common`

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
    styled_verdict,
    verdict,
    write_results,
)
from record_cost_traces import ORBITS, load_orbit_scene, orbit_camera

from cluster.balancing import BALANCERS, Balancer, CostAware, TracerReport, min_max_cuts
from cluster.connect import connect, disconnect
from cluster.coordinator import Coordinator
from cluster.scene_graph import SceneGraph
from tracer.request import FrameRequest
from tracer.scene.loader import load_scene
from worker.envelope import SceneEnvelope
from worker.work_units import WorkUnits

CORNELL = REPO_ROOT / "scenes" / "cornell-box" / "scene.json"
SETUPS = {
    "1 tracer x 1 cpu": (1, 1.0),
    "2 tracers x 1 cpu": (2, 1.0),
    "1 tracer x 2 cpus": (1, 2.0),
}


def scaling(size: int, spp: int, repeats: int) -> dict:
    """Frame seconds and overhead of each set-up, interleaved round by round."""
    state = load_scene(CORNELL)
    camera = state.camera.model_copy(update={"width": size, "height": size})
    settings = state.render.model_copy(update={"spp": spp})
    coordinators = {
        name: Coordinator(SceneGraph(state), tracers=n, cpus_per_tracer=cpus, balancer="none")
        for name, (n, cpus) in SETUPS.items()
    }
    walls = {name: [] for name in SETUPS}
    overheads = {name: [] for name in SETUPS}
    images = {}
    try:
        for c in coordinators.values():  # warm-up: kernels loaded, first snapshot compiled
            c.render_frame(FrameRequest(camera=camera, settings=settings))
        for _ in range(repeats):
            for name, c in coordinators.items():
                frame = c.render_frame(FrameRequest(camera=camera, settings=settings))
                walls[name].append(frame.wall_seconds)
                overheads[name].append(frame.overhead_seconds / frame.wall_seconds)
                images[name] = frame.rgb
    finally:
        for c in coordinators.values():
            c.close()
    first = images["1 tracer x 1 cpu"]
    identical = all((image == first).all() for image in images.values())
    return {
        "size": size,
        "spp": spp,
        "wall_seconds": walls,
        "median_seconds": {k: statistics.median(v) for k, v in walls.items()},
        "median_overhead": {k: statistics.median(v) for k, v in overheads.items()},
        "bit_identical": identical,
    }


class HindsightSplit(Balancer):
    """A yardstick, not a balancer to use: cuts each frame with the min-max partition of that
    frame's *true* unit costs (recorded in an earlier pass; pixels and costs are deterministic
    per frame) and each tracer's speed averaged over every frame seen so far. The idle it
    leaves is what timing noise alone costs on this machine: a floor for every balancer."""

    name = "hindsight"

    def __init__(self, costs: list[tuple[WorkUnits, np.ndarray]]) -> None:
        self.costs = costs
        """(units, cost per unit) of every frame, in order."""
        self.calls = 0
        self.work: dict[str, float] = {}
        self.seconds: dict[str, float] = {}

    def split(self, units: int, tracer_ids: list[str], spans: int = 1) -> list[tuple[int, int]]:
        layout, cost = self.costs[min(self.calls, len(self.costs) - 1)]
        self.calls += 1
        cost = cost.astype(np.float64)
        if cost.size != units:  # another layout (a tracer sat the frame out): lines spread
            cost = np.repeat(layout.per_line(cost) / spans, spans)
        known = [self.work[t] / self.seconds[t] for t in tracer_ids if self.seconds.get(t)]
        mean = statistics.fmean(known) if known else 1.0
        speeds = [
            self.work[t] / self.seconds[t] if self.seconds.get(t) else mean for t in tracer_ids
        ]
        cost = np.maximum(cost, CostAware.FLOOR * max(cost.mean(), 1e-300))
        return list(itertools.pairwise(min_max_cuts(cost, speeds)))

    def observe(self, units: int, reports: list[TracerReport], spans: int = 1) -> None:
        for r in reports:
            if r.u1 > r.u0 and r.seconds > 0:
                self.work[r.tracer] = self.work.get(r.tracer, 0.0) + float(r.unit_cost.sum())
                self.seconds[r.tracer] = self.seconds.get(r.tracer, 0.0) + r.seconds


def speed_noise(frames: list) -> float:
    """Timing noise: the coefficient of variation, over frames, of each tracer's speed (its
    range's cost per busy second), averaged over tracers, in %."""
    speeds: dict[str, list[float]] = {}
    for f in frames:
        for r in f.ranges:
            if r.kind == "split" and r.u1 > r.u0:
                work = float(f.unit_cost[r.u0 : r.u1].sum())
                speeds.setdefault(r.tracer, []).append(work / (r.seconds + r.apply_seconds))
    cvs = [np.std(v) / np.mean(v) for v in speeds.values() if len(v) > 2]
    return 100 * statistics.fmean(cvs) if cvs else float("nan")


def idle_real(
    frames: int, balancers: list[str], width: int, height: int, oracle: bool, sequential: bool
) -> dict:
    """Idle per orbit and balancer with two one-CPU tracers each, the balancers' coordinators
    taking turns frame by frame (so load on a shared machine hits them alike), or with
    ``sequential`` each rendering its whole orbit in turn (no switching between the
    coordinators' tracer processes, the steadier measure on a quiet machine); with
    ``oracle``, also the hindsight split (:class:`HindsightSplit`) of the costs the first
    balancer's run records as it goes. Per run: mean idle % (Table 16's measure, waits between
    a tracer's ranges counted), mean span idle % (over the wall time), mean wall ms per frame,
    frames per second, render calls per frame and the timing noise."""
    state, _ = load_orbit_scene()
    settings = state.render.model_copy(update={"spp": 1})
    names = [*balancers, *(["oracle"] if oracle else [])]
    out: dict = {key: {} for key in ("slow", "fast", "speed_noise_percent", "runs")}
    for orbit in ("slow", "fast"):
        degrees = ORBITS[orbit][0]
        cameras = [orbit_camera(degrees * k / frames, width, height) for k in range(frames)]
        recorded: list[tuple[WorkUnits, np.ndarray]] = []
        coordinators = {}
        try:
            for name in names:
                c = Coordinator(SceneGraph(state), tracers=2, cpus_per_tracer=1.0)
                coordinators[name] = c
                if name == "oracle":
                    c.balancer = HindsightSplit(recorded)
                else:
                    c.use_balancer(name)
            done: dict[str, list] = {name: [] for name in names}
            for name, c in coordinators.items():  # warm-up frame
                warm = c.render_frame(FrameRequest(camera=cameras[0], settings=settings))
                if name == names[0]:
                    recorded.append((warm.units, warm.unit_cost))
            if sequential:
                order = [(k, name) for name in names for k in range(frames)]
            else:
                order = [(k, name) for k in range(frames) for name in names]
            for k, name in order:  # the oracle comes after the first balancer's frame k
                c = coordinators[name]
                frame = c.render_frame(FrameRequest(frame=k, camera=cameras[k], settings=settings))
                done[name].append(frame)
                if name == names[0]:
                    recorded.append((frame.units, frame.unit_cost))
        finally:
            for c in coordinators.values():
                c.close()
        out["speed_noise_percent"][orbit] = {}
        out["runs"][orbit] = {}
        for name in names:
            run = done[name]
            walls = [f.wall_seconds for f in run]
            out[orbit][name] = statistics.fmean(f.idle_percent for f in run)
            out["speed_noise_percent"][orbit][name] = speed_noise(run)
            out["runs"][orbit][name] = {
                "idle": out[orbit][name],
                "span_idle": statistics.fmean(f.span_idle_percent for f in run),
                "wall_ms": 1e3 * statistics.fmean(walls),
                "frames_per_second": len(run) / sum(walls),
                "calls_per_frame": statistics.fmean(f.calls for f in run),
                "idle_per_frame": [round(f.idle_percent, 3) for f in run],
            }
            note(
                f"{orbit} orbit, {name}: {out[orbit][name]:.2f}% idle, span "
                f"{out['runs'][orbit][name]['span_idle']:.2f}%, "
                f"{out['runs'][orbit][name]['wall_ms']:.1f} ms per frame, speed noise "
                f"{out['speed_noise_percent'][orbit][name]:.1f}%"
            )
    return out


CALLS_MIN_HEIGHT = 480
"""Least image height of the calls section (smaller orbit sizes run it at 640x480)."""


PLOT_WINDOW = 8
"""Frames per point of the idle plot (a moving mean: single frames vary by several points)."""


def plot_idle(idle: dict, path: Path, title: str) -> bool:
    """Idle % per frame of every balancer, one panel per orbit (after Bikker's figure 48), as a
    moving mean over ``PLOT_WINDOW`` frames."""
    plt = pyplot()
    if plt is None:
        return False
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.4), sharey=True)
    for ax, orbit in zip(axes, ("slow", "fast"), strict=True):
        for name, run in idle["runs"][orbit].items():
            style = {"linestyle": ":", "color": "grey"} if name == "oracle" else {}
            label = "hindsight" if name == "oracle" else name
            window = np.ones(PLOT_WINDOW) / PLOT_WINDOW
            mean = np.convolve(run["idle_per_frame"], window, mode="valid")
            frames = np.arange(mean.size) + PLOT_WINDOW - 1
            ax.plot(frames, mean, label=label, linewidth=1.2, **style)
        ax.set_yscale("log")
        ax.set_ylim(0.3, 60)
        ax.axhline(1.0 if orbit == "slow" else 2.0, color="black", linewidth=0.5)
        ax.set_title(
            f"{orbit} orbit: idle %, mean of {PLOT_WINDOW} frames (line: the target)", fontsize=9
        )
        ax.set_xlabel("frame", fontsize=8)
        ax.tick_params(labelsize=7)
    axes[0].set_ylabel("idle %", fontsize=8)
    handles, names = axes[0].get_legend_handles_labels()
    fig.legend(handles, names, loc="upper center", ncol=min(len(names), 8), fontsize=8)
    fig.suptitle(title, fontsize=9, y=0.02, va="bottom")
    fig.tight_layout(rect=(0, 0.05, 1, 0.9))
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=72)
    plt.close(fig)
    console.print(f"[dim]plot written to {path.relative_to(REPO_ROOT)}[/]")
    return True


def call_costs(width: int, height: int, repeats: int) -> dict:
    """What a render call costs a real tracer outside rendering (the simulator's
    ``--latency-ms`` and ``--call-gap-ms``), on the orbit scene at ``width`` x ``height``:
    the round trip of a one-line call minus its render seconds; the time between calls
    queued back to back (30 four-line calls behind a long one, so none waits for its
    submission): their wall time minus busy time and one round trip, per call; and the fixed
    work inside a call (its busy seconds beyond its lines'): 40 lines as ten calls against the
    same lines as one, per extra call."""
    state, _ = load_orbit_scene()
    settings = state.render.model_copy(update={"spp": 1})
    camera = orbit_camera(0.0, width, height)
    trips, gaps, fixed = [], [], []
    with Coordinator(SceneGraph(state), tracers=1, cpus_per_tracer=1.0) as c:
        request = FrameRequest(camera=camera, settings=settings)
        envelope = SceneEnvelope(c.graph.key, c.render_frame(request).version)
        handle = c.tracer_handle(c.ready[0])

        def call(y0: int, y1: int):
            return handle.render.remote(envelope, request.for_units(y0, y1))

        for _ in range(repeats):
            for _ in range(10):
                start = time.perf_counter()
                out = ray.get(call(height // 4, height // 4 + 1))
                trips.append(time.perf_counter() - start - out.seconds - out.apply_seconds)
            trip = statistics.median(trips[-10:])
            start = time.perf_counter()
            refs = [call(height // 2, height)] + [
                call(height - 40 + k, height - 36 + k) for k in range(30)
            ]
            outs = ray.get(refs)
            wall = time.perf_counter() - start
            busy = sum(o.seconds + o.apply_seconds for o in outs)
            gaps.append((wall - busy - trip) / 30)
            a = height // 2 + height // 8
            whole = ray.get(call(a, a + 40))
            parts = ray.get([call(a + 4 * k, a + 4 * k + 4) for k in range(10)])
            extra = sum(p.seconds + p.apply_seconds for p in parts) - whole.seconds
            fixed.append((extra - whole.apply_seconds) / 9)
    return {
        "round_trip_minus_render_ms": 1e3 * statistics.median(trips),
        "queued_gap_ms": 1e3 * statistics.median(gaps),
        "queued_gap_ms_all": [round(1e3 * g, 3) for g in gaps],
        "fixed_in_call_ms": 1e3 * statistics.median(fixed),
        "size": [width, height],
    }


def recovery(size: int, spp: int) -> dict:
    """Seconds from a SIGKILL of one of two tracers mid-frame to the frame's completion."""
    state = load_scene(CORNELL)
    camera = state.camera.model_copy(update={"width": size, "height": size})
    settings = state.render.model_copy(update={"spp": spp})
    with Coordinator(
        SceneGraph(state), tracers=2, cpus_per_tracer=1.0, balancer="none", straggler_floor=60.0
    ) as c:
        c.render_frame(FrameRequest(camera=camera, settings=settings))
        clean = c.render_frame(FrameRequest(frame=1, camera=camera, settings=settings))
        victim = c.tracers()[1]
        killed_at = {}

        def kill() -> None:
            time.sleep(clean.wall_seconds * 0.4)
            killed_at["t"] = time.perf_counter()
            os.kill(victim["pid"], signal.SIGKILL)

        killer = threading.Thread(target=kill)
        killer.start()
        failed = c.render_frame(FrameRequest(frame=1, camera=camera, settings=settings))
        done = time.perf_counter()
        killer.join()
        identical = bool((failed.rgb == clean.rgb).all())
    return {
        "clean_seconds": clean.wall_seconds,
        "with_kill_seconds": failed.wall_seconds,
        "kill_to_done_seconds": done - killed_at["t"],
        "failures": failed.failures,
        "bit_identical": identical,
    }


def start_nodes(cpus_each: int):
    """A ``ray.cluster_utils.Cluster`` on this machine: a head without CPUs (where this
    process, the coordinator, attaches) and two worker nodes of ``cpus_each`` CPUs."""
    from ray.cluster_utils import Cluster

    nodes = Cluster(initialize_head=True, head_node_args={"num_cpus": 0})
    for _ in range(2):
        nodes.add_node(num_cpus=cpus_each)
    nodes.wait_for_nodes()
    return nodes


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], epilog="Quick check: --quick"
    )
    parser.add_argument("--size", type=int, default=512, help="scaling image side (512)")
    parser.add_argument("--spp", type=int, default=16, help="scaling samples per pixel (16)")
    parser.add_argument("--overhead-size", type=int, default=256, help="overhead image side")
    parser.add_argument("--repeats", type=int, default=5, help="interleaved rounds (5)")
    parser.add_argument("--frames", type=int, default=128, help="orbit frames (128)")
    parser.add_argument("--orbit-size", type=int, nargs=2, default=[128, 96], metavar=("W", "H"))
    parser.add_argument("--balancers", nargs="+", default=list(BALANCERS), choices=list(BALANCERS))
    parser.add_argument(
        "--skip", nargs="*", default=[], choices=["scaling", "idle", "recovery", "calls"]
    )
    parser.add_argument(
        "--no-oracle",
        action="store_true",
        help="skip the hindsight split (exact costs of each frame, recorded by the first "
        "balancer's run): the idle that timing noise alone leaves",
    )
    parser.add_argument(
        "--sequential",
        action="store_true",
        help="idle section: each balancer renders its whole orbit in turn instead of the "
        "balancers taking turns frame by frame (steadier on a quiet machine; fair only if the "
        "load does not change)",
    )
    parser.add_argument(
        "--nodes",
        action="store_true",
        help="run on a ray.cluster_utils.Cluster of this machine (a head without CPUs, the "
        "coordinator's, and two worker nodes) instead of one embedded Ray: tracers are then "
        "on other nodes than the coordinator, so pooled tails go to the actor pool "
        "(worker.remote_pool) instead of the shared-memory file",
    )
    parser.add_argument("--quick", action="store_true", help="small sizes, few frames")
    args = parser.parse_args(argv)
    if args.quick:
        args.size, args.spp, args.overhead_size, args.repeats, args.frames = 128, 4, 64, 2, 8

    info = machine_info()
    print_machine(info)
    # Room for every set-up's tracers at once (they take turns; only one renders at a time).
    runs = len(args.balancers) + (0 if args.no_oracle else 1)
    cpus = max(int(sum(n * cpus for n, cpus in SETUPS.values())), 2 * runs)
    nodes = start_nodes((cpus + 1) // 2) if args.nodes else None
    payload: dict = {"options": vars(args)}
    try:
        connect(nodes.address if nodes else None, num_cpus=None if nodes else cpus)
        if "scaling" not in args.skip:
            big = scaling(args.size, args.spp, args.repeats)
            small = scaling(args.overhead_size, args.spp, args.repeats)
            payload["scaling"], payload["overhead"] = big, small
            one = big["median_seconds"]["1 tracer x 1 cpu"]
            two = big["median_seconds"]["2 tracers x 1 cpu"]
            threads = big["median_seconds"]["1 tracer x 2 cpus"]
            print_table(
                f"Scaling: Cornell box {args.size}x{args.size}, {args.spp} spp "
                f"(median of {args.repeats}, interleaved)",
                ["set-up", "seconds", "speed-up", f"overhead at {args.overhead_size}²"],
                [
                    [name, fmt_float(s, 3), fmt_float(one / s),
                     f"{100 * small['median_overhead'][name]:.1f}%"]
                    for name, s in big["median_seconds"].items()
                ],
            )  # fmt: skip
            overhead = max(small["median_overhead"].values())
            print_table(
                "Targets",
                ["target", "measured", "verdict"],
                [
                    ["2 tracers >= 1.8x 1 tracer", fmt_float(one / two),
                     styled_verdict(verdict(one / two, 1.8))],
                    ["2 tracers within 10% of 1 tracer x 2 threads", fmt_float(two / threads),
                     styled_verdict(verdict(two / threads, 1.10, at_most=True))],
                    [f"overhead <= 5% at {args.overhead_size}²", f"{100 * overhead:.1f}%",
                     styled_verdict(verdict(overhead, 0.05, at_most=True))],
                    ["frames bit-identical across set-ups", str(big["bit_identical"]),
                     styled_verdict("PASS" if big["bit_identical"] else "MISS")],
                ],
            )  # fmt: skip
        if "idle" not in args.skip:
            width, height = args.orbit_size
            idle = idle_real(
                args.frames, args.balancers, width, height, not args.no_oracle, args.sequential
            )
            payload["idle_real"] = idle
            protocol = "one after another" if args.sequential else "taking turns frame by frame"
            plot_idle(
                idle,
                RESULTS_DIR / "cluster_idle.png",
                f"2 real tracers, {width}x{height}, {args.frames} frames, balancers {protocol}",
            )
            rows = [*args.balancers, *([] if args.no_oracle else ["oracle"])]
            noise, runs = idle["speed_noise_percent"], idle["runs"]

            def both(b: str, key: str, digits: int = 2) -> str:
                return f"{runs['slow'][b][key]:.{digits}f} / {runs['fast'][b][key]:.{digits}f}"

            print_table(
                f"Idle % with 2 real tracers (1 CPU each), {args.frames} frames, {width}x{height},"
                + (" one balancer after another" if args.sequential
                   else " balancers taking turns frame by frame")
                + " (idle: Table 16's measure, waits between"
                " a tracer's ranges counted; span: over the wall time; speed noise: CV of each"
                " tracer's cost per second over frames)",
                ["balancer", "slow orbit", "fast orbit", "span idle slow / fast",
                 "ms per frame slow / fast", "frames/s slow / fast", "calls per frame",
                 "speed noise slow / fast"],
                [[b, fmt_float(idle["slow"][b]), fmt_float(idle["fast"][b]),
                  both(b, "span_idle"), both(b, "wall_ms", 1), both(b, "frames_per_second"),
                  both(b, "calls_per_frame", 1),
                  f"{noise['slow'][b]:.1f}% / {noise['fast'][b]:.1f}%"] for b in rows],
            )  # fmt: skip
        if "calls" not in args.skip:
            # Its calls take ranges in the lower 40 + height / 8 lines: at least 480 lines.
            width, height = (args.orbit_size if args.orbit_size[1] >= CALLS_MIN_HEIGHT
                             else (640, CALLS_MIN_HEIGHT))  # fmt: skip
            calls = call_costs(width, height, max(3, args.repeats))
            payload["calls"] = calls
            print_table(
                f"A render call's cost outside rendering (orbit scene, {width}x{height}; the "
                "simulator's --latency-ms is half the round trip, --call-gap-ms the queued gap)",
                ["round trip - render ms", "queued gap ms per call", "queued gap, each round",
                 "fixed work in a call ms"],
                [[fmt_float(calls["round_trip_minus_render_ms"], 3),
                  fmt_float(calls["queued_gap_ms"], 3),
                  ", ".join(f"{g:.2f}" for g in calls["queued_gap_ms_all"]),
                  fmt_float(calls["fixed_in_call_ms"], 3)]],
            )  # fmt: skip
        if "recovery" not in args.skip:
            rec = recovery(args.overhead_size, args.spp * 4)
            payload["recovery"] = rec
            print_table(
                "Recovery: one of two tracers SIGKILLed 40% into a frame",
                ["clean frame s", "frame with kill s", "kill -> frame done s", "bit-identical"],
                [[fmt_float(rec["clean_seconds"], 3), fmt_float(rec["with_kill_seconds"], 3),
                  fmt_float(rec["kill_to_done_seconds"], 3), str(rec["bit_identical"])]],
            )  # fmt: skip
    finally:
        disconnect()
        if nodes is not None:
            nodes.shutdown()
    write_results("cluster", payload, info)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

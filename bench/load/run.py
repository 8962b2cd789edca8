"""The long load profile and the chaos runs, against a real server on 127.0.0.1.

    python bench/load/run.py                          # 20 users, 60 s, then a full queue
    python bench/load/run.py --chaos kill-tracer      # SIGKILL a tracer part-way through
    python bench/load/run.py --chaos remove-node      # ray start topology; a worker node dies

Starts the service (``--nodes embedded``: ``tilerender serve --tracers 2 --threads 1`` with
its own Ray; ``--nodes ray-start``: a 0-CPU ``ray start`` head, two one-CPU workers and
``tilerender serve --ray-address``, as the compose file runs them; ``remove-node`` implies
it), warms the kernels up, runs ``locustfile.py`` headless (``--users`` for ``--seconds``),
fires the chaos action at ``--chaos-at`` of the run, waits until every job has ended, checks
every result against a local render (bit-identical), and, without chaos, probes a full queue.

Prints the per-endpoint table (requests/s, p50/p95/p99, failures), jobs submitted vs
completed, frames streamed and the verdicts; writes ``bench/results/load[_CHAOS].json`` and
the locust CSV files under ``--out``. Targets: 0 failures, 0 lost jobs, every result equal
to its reference, status p99 <= 50 ms, a full queue answers 429 (never a timeout).
"""

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
REPO_ROOT = HERE.parents[1]
sys.path[:0] = [str(REPO_ROOT), str(HERE.parent)]

import httpx  # noqa: E402
from common import machine_info, print_machine, verdict, write_results  # noqa: E402

from bench.load import harness  # noqa: E402

STATUS_P99_TARGET_MS = 50.0
MAX_QUEUE = 16


def parse_args(argv=None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--users", type=int, default=20)
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--chaos", choices=["none", "kill-tracer", "remove-node"], default="none")
    parser.add_argument("--chaos-at", type=float, default=0.4, help="fraction of the run")
    parser.add_argument("--nodes", choices=["embedded", "ray-start"], default="embedded")
    parser.add_argument("--tracers", type=int, default=2, help="tracers (worker nodes)")
    parser.add_argument("--out", type=Path, default=None, help="locust CSVs and logs")
    return parser.parse_args(argv)


def chaos_action(name: str, url: str, topology) -> harness.Chaos | None:
    if name == "kill-tracer":
        return harness.Chaos(name, 0.0, lambda: harness.kill_a_tracer(url))
    if name == "remove-node":

        def remove() -> str:
            node = topology.workers[-1]
            node.kill()
            return f"SIGKILL to every process of Ray node {node.role} (raylet, tracer, agents)"

        return harness.Chaos(name, 0.0, remove)
    return None


def check(ok: bool) -> str:
    return "PASS" if ok else "MISS"


def main(argv=None) -> int:
    args = parse_args(argv)
    nodes = "ray-start" if args.chaos == "remove-node" else args.nodes
    name = "load" if args.chaos == "none" else f"load_{args.chaos.replace('-', '_')}"
    out = args.out or Path(tempfile.mkdtemp(prefix=f"tilerender-{name}-"))
    profile = harness.Profile(users=args.users, seconds=args.seconds, spawn_rate=args.users)
    machine = machine_info()
    print_machine(machine)
    with harness.service(out, nodes, args.tracers) as (api, topology):
        http = httpx.Client(base_url=api.url, timeout=60)
        warm = harness.warm_up(http)
        print(f"warm-up: {', '.join(f'{k} {v:.1f} s' for k, v in warm.items())}")
        chaos = chaos_action(args.chaos, api.url, topology)
        if chaos is not None:
            chaos.at = args.chaos_at * args.seconds
        cpu = harness.CpuMeter(api.process.pid, http)
        run = harness.run_profile(api.url, profile, out / "locust", chaos)
        cpu_seconds = cpu.stop()
        started = time.monotonic()
        run.jobs = harness.settle(http)
        settle_seconds = time.monotonic() - started
        run.results = harness.check_results(http, run.jobs, run.locust_jobs, harness.References())
        cluster = http.get("/v1/cluster").json()
        full_queue = None
        if chaos is None:
            full_queue = harness.probe_full_queue(http, harness.upload(http, "cornell"), MAX_QUEUE)
            full_queue["cancelled"] = len(full_queue["cancelled"])
    print(harness.format_run(run))
    print(f"settled {settle_seconds:.1f} s after locust stopped")
    print(
        f"CPU seconds during the run ({run.wall_seconds:.0f} s wall): "
        + ", ".join(f"{k} {v:.1f}" for k, v in cpu_seconds.items())
    )
    tracers = [(t["id"], t["state"], t["failures"]) for t in cluster["tracers"]]
    print(f"tracers after the run (id, state, failures): {tracers}")
    if full_queue is not None:
        print(f"full queue: {full_queue}")
    jobs = run.job_counts()
    status = run.endpoint("/v1/jobs/[id]")
    verdicts = {
        "no failed request": check(run.failures == 0),
        "jobs submitted == completed": check(jobs["submitted"] == jobs["completed"]),
        "results equal references": check(
            not run.results["mismatched"] and not run.results["unverified"]
        ),
        "status p99 <= 50 ms": verdict(status["p99"], STATUS_P99_TARGET_MS, at_most=True),
    }
    if full_queue is not None:
        verdicts["full queue: 429 within 1 s"] = check(
            full_queue["all_429"] and full_queue["max_ms"] < 1000
        )
    if chaos is not None:
        verdicts["chaos hit a tracer"] = check(sum(t["failures"] for t in cluster["tracers"]) > 0)
    for key, value in verdicts.items():
        print(f"{value}  {key}")
    (out / "summary.md").write_text(harness.format_run(run) + "\n")
    write_results(
        name,
        {
            **run.summary(),
            "warm_up_seconds": warm,
            "settle_seconds": settle_seconds,
            "cpu_seconds": cpu_seconds,
            "load_average_after": list(os.getloadavg()),
            "nodes": nodes,
            "tracers": cluster["tracers"],
            "full_queue": full_queue,
            "verdicts": verdicts,
            "out": str(out),
        },
        machine,
    )
    return 0 if all(v == "PASS" for v in verdicts.values()) else 1


if __name__ == "__main__":
    sys.exit(main())

"""Soak: the load mix for 10 minutes while the resident memory of the API process and of each
tracer process is sampled; writes a CSV and a plot and states each process's slope.

    python bench/load/soak.py                        # 20 users, 600 s, a sample every 5 s
    python bench/load/soak.py --seconds 60 --users 5 # a quick check

The service is ``tilerender serve --tracers 2 --threads 1`` (its own embedded Ray) on
127.0.0.1. Every ``--interval`` seconds a thread reads the RSS (``psutil``) of the API process
and of each tracer (pids from ``GET /v1/cluster``; a tracer whose pid changes is noted).
After the run every job must have completed with its result equal to a local render.

Slope: a least-squares line through each process's samples after ``--warm-up`` seconds, in
MiB per minute; *flat* means the line's rise over that window is under ``--flat-percent`` of
the process's mean RSS. Writes ``docs/load/soak_rss.csv`` and ``docs/load/soak_rss.png``
(``--docs``) and ``bench/results/load_soak.json``.
"""

import argparse
import csv
import sys
import tempfile
import threading
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
REPO_ROOT = HERE.parents[1]
sys.path[:0] = [str(REPO_ROOT), str(HERE.parent)]

import httpx  # noqa: E402
import numpy as np  # noqa: E402
import psutil  # noqa: E402
from common import machine_info, print_machine, print_table, write_results  # noqa: E402

from bench.load import harness  # noqa: E402

MiB = 1024 * 1024


class RssSampler(threading.Thread):
    """Samples the RSS of the API process and each tracer every ``interval`` seconds."""

    def __init__(self, url: str, api_pid: int, interval: float) -> None:
        super().__init__(daemon=True)
        self.url, self.api_pid, self.interval = url, api_pid, interval
        self.rows: list[dict] = []
        self.pids: dict[str, set[int]] = {}
        self.stop_event = threading.Event()
        self.started = time.monotonic()

    def sample(self) -> dict:
        row = {"seconds": time.monotonic() - self.started, "api": rss(self.api_pid)}
        tracers = httpx.get(self.url + "/v1/cluster", timeout=10).json()["tracers"]
        for tracer in tracers:
            if tracer["pid"]:
                self.pids.setdefault(tracer["id"], set()).add(tracer["pid"])
                row[tracer["id"]] = rss(tracer["pid"])
        return row

    def run(self) -> None:
        while not self.stop_event.is_set():
            try:
                self.rows.append(self.sample())
            except (httpx.HTTPError, psutil.Error):
                pass  # a missed sample; the next one comes
            self.stop_event.wait(self.interval)

    def stop(self) -> None:
        self.stop_event.set()
        self.join(30)


def rss(pid: int) -> float | None:
    try:
        return psutil.Process(pid).memory_info().rss / MiB
    except psutil.Error:
        return None


def slopes(rows: list[dict], after: float, flat_percent: float) -> list[dict]:
    """Per process: first, last, peak and mean RSS, and the least-squares slope (MiB/min)
    over the samples after ``after`` seconds."""
    names = [k for k in rows[0] if k != "seconds"]
    out = []
    for name in names:
        points = [(r["seconds"], r[name]) for r in rows if r.get(name) is not None]
        window = [(t, v) for t, v in points if t >= after]
        t = np.array([p[0] for p in window]) / 60.0
        v = np.array([p[1] for p in window])
        slope = float(np.polyfit(t, v, 1)[0]) if len(window) >= 3 else float("nan")
        rise = slope * (t[-1] - t[0]) if len(window) >= 3 else float("nan")
        out.append(
            {
                "process": name,
                "first_mib": points[0][1],
                "last_mib": points[-1][1],
                "peak_mib": max(p[1] for p in points),
                "mean_mib": float(v.mean()),
                "slope_mib_per_min": slope,
                "rise_mib": rise,
                "flat": bool(abs(rise) < flat_percent / 100 * v.mean()),
            }
        )
    return out


def write_csv(rows: list[dict], path: Path) -> None:
    names = [k for k in rows[0] if k != "seconds"]
    with open(path, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["seconds", *(f"{n}_rss_mib" for n in names)])
        for row in rows:
            cells = [f"{row['seconds']:.1f}"]
            cells += ["" if row.get(n) is None else f"{row[n]:.1f}" for n in names]
            writer.writerow(cells)


def plot(rows: list[dict], fits: list[dict], after: float, path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 4.5), dpi=110)
    for fit in fits:
        name = fit["process"]
        points = [(r["seconds"] / 60, r[name]) for r in rows if r.get(name) is not None]
        who = "API" if name == "api" else f"tracer {name}"
        label = f"{who}: {fit['slope_mib_per_min']:+.2f} MiB/min"
        ax.plot([p[0] for p in points], [p[1] for p in points], label=label)
    ax.axvline(after / 60, color="grey", linestyle=":", linewidth=1)
    ax.set_xlabel("minutes")
    ax.set_ylabel("resident memory (MiB)")
    ax.set_ylim(bottom=0)
    ax.set_title(title, fontsize=10)
    ax.legend(loc="lower right", fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--users", type=int, default=20)
    parser.add_argument("--seconds", type=float, default=600.0)
    parser.add_argument("--interval", type=float, default=5.0, help="seconds between samples")
    parser.add_argument("--warm-up", type=float, default=60.0, help="seconds left out of fits")
    parser.add_argument("--flat-percent", type=float, default=5.0)
    parser.add_argument("--docs", type=Path, default=REPO_ROOT / "docs" / "load")
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args(argv)
    out = args.out or Path(tempfile.mkdtemp(prefix="tilerender-soak-"))
    machine = machine_info()
    print_machine(machine)
    profile = harness.Profile(users=args.users, seconds=args.seconds, spawn_rate=args.users)
    with harness.service(out, "embedded", 2) as (api, _):
        http = httpx.Client(base_url=api.url, timeout=60)
        harness.warm_up(http)
        sampler = RssSampler(api.url, api.process.pid, args.interval)
        sampler.start()
        run = harness.run_profile(api.url, profile, out / "locust", timeout=args.seconds + 600)
        run.jobs = harness.settle(http)
        sampler.stop()
        run.results = harness.check_results(http, run.jobs, run.locust_jobs, harness.References())
    print(harness.format_run(run))
    fits = slopes(sampler.rows, args.warm_up, args.flat_percent)
    print_table(
        "resident memory",
        ["process", "first MiB", "last MiB", "peak MiB", "slope MiB/min", "rise MiB", "flat"],
        [
            [
                f["process"],
                f"{f['first_mib']:.0f}",
                f"{f['last_mib']:.0f}",
                f"{f['peak_mib']:.0f}",
                f"{f['slope_mib_per_min']:+.3f}",
                f"{f['rise_mib']:+.1f}",
                "yes" if f["flat"] else "NO",
            ]
            for f in fits
        ],
    )
    restarted = {k: sorted(v) for k, v in sampler.pids.items() if len(v) > 1}
    if restarted:
        print(f"tracers whose pid changed: {restarted}")
    args.docs.mkdir(parents=True, exist_ok=True)
    write_csv(sampler.rows, args.docs / "soak_rss.csv")
    jobs = run.job_counts()
    title = (
        f"soak: {args.users} users, {args.seconds / 60:g} min, {jobs['completed']} jobs, "
        f"{run.counts.get('frames streamed', 0)} frames streamed"
    )
    plot(sampler.rows, fits, args.warm_up, args.docs / "soak_rss.png", title)
    print(f"wrote {args.docs / 'soak_rss.csv'} and {args.docs / 'soak_rss.png'}")
    write_results(
        "load_soak",
        {**run.summary(), "rss": fits, "samples": len(sampler.rows), "restarted": restarted},
        machine,
    )
    ok = (
        run.failures == 0
        and jobs["submitted"] == jobs["completed"]
        and not run.results["mismatched"]
        and all(f["flat"] for f in fits)
    )
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())

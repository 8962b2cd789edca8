"""The service while the biggest job it allows renders: health, a session, a camera move,
a cancel.

Starts ``tilerender serve`` on 127.0.0.1 (a free port, a temporary data directory, its own
embedded Ray), uploads the Cornell box and submits a job at the service's limits (3840x2160 at
4096 spp by default: hours of work, one frame). While it renders, for ``--seconds``:

1. ``GET /healthz`` polled by ``--clients`` threads: p50/p99/max. Target: p99 <= 50 ms.
2. A 320x180 session's MJPEG stream: the longest gap between two frames. Target: <= 2 s.
3. ``--updates`` camera moves (``PUT .../camera``), each timed from the PUT to the second frame
   after its answer (the frame in flight when the move arrived cannot show it). Target: <= 1 s.

Then the session closes and the job is cancelled: the time from the cancel's answer until the
tracer processes stop working (their CPU use, sampled every 20 ms, falls under a tenth of a
core for 100 ms; target <= 2 s), and how long a small job submitted then takes. ``--kind``
picks the big job: ``spp`` (a frame by samples per pixel), ``target`` (a progressive frame to an
error target) or ``both``.

    python bench/heavy_job.py [--seconds 20] [--updates 10] [--kind both]
"""

import argparse
import itertools
import json
import os
import signal
import subprocess
import tempfile
import threading
import time
from pathlib import Path

import psutil
from api_latency import StreamReader, percentiles, start_server, upload_cornell
from common import (
    fmt_float,
    machine_info,
    print_machine,
    print_table,
    styled_verdict,
    verdict,
    write_results,
)

STOPPED_CPU = 0.1
"""Tracers count as stopped below this many cores of CPU use ..."""
STOPPED_FOR = 0.1
"""... held for this many seconds."""


def big_job(kind: str, scene: str, width: int, height: int, spp: int) -> dict:
    body = {"scene_id": scene, "width": width, "height": height}
    if kind == "spp":
        return {**body, "spp": spp}
    return {**body, "target_error": 0.001, "max_spp": spp}


def wait_running(http, job_id: str) -> None:
    deadline = time.monotonic() + 120
    while http.get(f"/v1/jobs/{job_id}").json()["status"] != "running":
        if time.monotonic() > deadline:
            raise SystemExit("the big job never started")
        time.sleep(0.05)


def poll_health(url: str, stop: float, clients: int) -> list[float]:
    import httpx

    times: list[float] = []
    lock = threading.Lock()

    def poll() -> None:
        with httpx.Client(base_url=url, timeout=30) as client:
            while time.monotonic() < stop:
                start = time.perf_counter()
                client.get("/healthz").raise_for_status()
                with lock:
                    times.append(time.perf_counter() - start)
                time.sleep(0.01)

    threads = [threading.Thread(target=poll) for _ in range(clients)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return times


def session_under_load(http, url: str, scene: str, seconds: float, updates: int) -> dict:
    session = http.post(
        "/v1/sessions", json={"scene_id": scene, "width": 320, "height": 180}
    ).json()
    reader = StreamReader(url + session["stream_url"])
    reader.start()
    opened = time.perf_counter()
    while not reader.arrivals and time.perf_counter() - opened < 30:
        time.sleep(0.01)
    first_frame = time.perf_counter() - opened
    moves = []
    end = time.perf_counter() + seconds
    for k in range(updates):
        camera = {"position": [0.05 * (k + 1), 0.0, 3.9], "look_at": [0.0, 0.0, 2.9]}
        sent = time.perf_counter()
        http.put(f"/v1/sessions/{session['id']}/camera", json=camera).raise_for_status()
        answered = time.perf_counter()
        while sum(1 for a in reader.arrivals if a > answered) < 2:
            if time.perf_counter() - sent > 30:
                break
            time.sleep(0.001)
        shown = [a for a in reader.arrivals if a > answered]
        moves.append((shown[1] if len(shown) > 1 else time.perf_counter()) - sent)
        time.sleep(max(0.0, (end - time.perf_counter()) / max(1, updates - k)))
    while time.perf_counter() < end:
        time.sleep(0.05)
    arrivals = list(reader.arrivals)
    reader.stopped = True
    http.delete(f"/v1/sessions/{session['id']}")
    gaps = [b - a for a, b in itertools.pairwise(arrivals)]
    return {
        "first_frame_s": first_frame,
        "frames": len(arrivals),
        "max_gap_s": max(gaps, default=float("inf")),
        "moves": percentiles(moves) if moves else None,
    }


def tracer_processes(http) -> list[psutil.Process]:
    found = []
    for tracer in http.get("/v1/cluster").json()["tracers"]:
        if tracer.get("pid"):
            try:
                found.append(psutil.Process(tracer["pid"]))
            except psutil.NoSuchProcess:
                pass
    return found


def cpu_seconds(processes: list[psutil.Process]) -> float:
    total = 0.0
    for p in processes:
        try:
            t = p.cpu_times()
            total += t.user + t.system
        except psutil.NoSuchProcess:
            pass
    return total


def cancel_and_time(http, job_id: str, scene: str) -> dict:
    """Seconds from the cancel's answer until the tracers stop working, then how long a small
    job submitted after that takes."""
    processes = tracer_processes(http)
    http.post(f"/v1/jobs/{job_id}/cancel").raise_for_status()
    cancelled = time.perf_counter()
    stopped = quiet_since = None
    last_cpu, last_at = cpu_seconds(processes), cancelled
    while stopped is None and time.perf_counter() - cancelled < 600:
        time.sleep(0.02)
        now, cpu = time.perf_counter(), cpu_seconds(processes)
        busy = (cpu - last_cpu) / max(1e-6, now - last_at)
        last_cpu, last_at = cpu, now
        if busy >= STOPPED_CPU:
            quiet_since = None
        elif quiet_since is None:
            quiet_since = last_at
        elif now - quiet_since >= STOPPED_FOR:
            stopped = quiet_since - cancelled
    body = {"scene_id": scene, "spp": 1, "width": 16, "height": 16}
    submitted = time.perf_counter()
    small = http.post("/v1/jobs", json=body).json()["id"]
    while http.get(f"/v1/jobs/{small}").json()["status"] not in ("done", "failed"):
        time.sleep(0.02)
    return {"tracers_stopped_s": stopped, "small_job_s": time.perf_counter() - submitted}


def run_kind(http, url: str, scene: str, kind: str, args) -> dict:
    job = http.post("/v1/jobs", json=big_job(kind, scene, args.width, args.height, args.spp))
    job.raise_for_status()
    job_id = job.json()["id"]
    wait_running(http, job_id)
    stop = time.monotonic() + args.seconds
    health: list[float] = []
    poller = threading.Thread(
        target=lambda: health.extend(poll_health(url, stop, args.clients)), daemon=True
    )
    poller.start()
    session = session_under_load(http, url, scene, args.seconds, args.updates)
    poller.join()
    progress = http.get(f"/v1/jobs/{job_id}").json()["progress"]
    cancel = cancel_and_time(http, job_id, scene)
    return {
        "kind": kind,
        "health": percentiles(health),
        "session": session,
        "cancel": cancel,
        "samples_done": progress["samples_done"],
    }


def report(results: list[dict], args) -> None:
    rows = []
    for r in results:
        moves = r["session"]["moves"] or {}
        move_max = moves.get("max_ms", float("inf")) / 1000
        stopped = r["cancel"]["tracers_stopped_s"]
        rows.append(
            [
                r["kind"],
                fmt_float(r["health"]["p99_ms"]),
                styled_verdict(verdict(r["health"]["p99_ms"], 50.0, at_most=True)),
                fmt_float(r["session"]["max_gap_s"], 2),
                styled_verdict(verdict(r["session"]["max_gap_s"], 2.0, at_most=True)),
                fmt_float(move_max, 2),
                styled_verdict(verdict(move_max, 1.0, at_most=True)),
                "-" if stopped is None else fmt_float(stopped, 2),
                styled_verdict(verdict(1e9 if stopped is None else stopped, 2.0, at_most=True)),
                fmt_float(r["cancel"]["small_job_s"], 2),
            ]
        )
    print_table(
        f"While a {args.width}x{args.height} job at {args.spp} spp renders "
        f"({args.seconds:g} s, {args.clients} health pollers)",
        ["job", "healthz p99 ms", "<= 50", "session max gap s", "<= 2", "camera move max s",
         "<= 1", "cancel -> tracers idle s", "<= 2", "small job after s"],
        rows,
    )  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=20.0, help="measuring time per job")
    parser.add_argument("--clients", type=int, default=2, help="concurrent health pollers")
    parser.add_argument("--updates", type=int, default=10, help="camera moves to time")
    parser.add_argument("--kind", choices=["spp", "target", "both"], default="both")
    parser.add_argument("--width", type=int, default=3840)
    parser.add_argument("--height", type=int, default=2160)
    parser.add_argument("--spp", type=int, default=4096)
    args = parser.parse_args()

    import httpx

    machine = machine_info()
    print_machine(machine)
    kinds = ["spp", "target"] if args.kind == "both" else [args.kind]
    results = []
    with tempfile.TemporaryDirectory() as data:
        process, url = start_server(Path(data), [])
        try:
            http = httpx.Client(base_url=url, timeout=60)
            scene = upload_cornell(http)
            for kind in kinds:
                results.append(run_kind(http, url, scene, kind, args))
        finally:
            process.send_signal(signal.SIGINT)
            try:
                process.wait(30)
            except subprocess.TimeoutExpired:
                process.kill()
    report(results, args)
    write_results("heavy_job", {"options": vars(args), "results": results}, machine)
    if os.environ.get("BENCH_PRINT_JSON"):
        print(json.dumps(results, indent=2))


if __name__ == "__main__":
    main()

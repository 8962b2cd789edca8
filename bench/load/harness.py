"""Load runs against a real server, and everything checked afterwards.

``run_profile`` runs ``locustfile.py`` headless in a subprocess (locust patches the standard
library with gevent, so it stays out of this process), with an optional *chaos* action fired
in a thread part-way through. Then:

1. ``settle``: waits until no job on the server is queued or running, and lists them all;
2. ``check_results``: downloads every job's NPY result and compares it, bit for bit, with a
   local render of the same scene and settings (``tracer.render.render_image``: what
   ``tilerender render`` computes, without Ray), one reference per distinct request;
3. ``probe_full_queue``: fills the queue with slow jobs and times the 429 answers.

The per-endpoint table comes from locust's ``--csv`` statistics; the counters (jobs
submitted, frames streamed, ...) from the locustfile's ``--results-file``.
"""

import contextlib
import csv
import io
import json
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import httpx
import numpy as np

HERE = Path(__file__).resolve().parent
REPO_ROOT = HERE.parents[1]
LOCUSTFILE = HERE / "locustfile.py"
SCENE_FILES = {
    "cornell": REPO_ROOT / "scenes" / "cornell-box" / "scene.json",
    "many-lights": REPO_ROOT / "scenes" / "many-lights" / "scene.json",
}
SCENE_NAMES = {"load-cornell": "cornell", "load-many-lights": "many-lights"}
"""Scene name on the server (the locustfile's uploads) -> key of SCENE_FILES."""
TERMINAL = ("done", "failed", "cancelled")
STATUS_ROUTE = "/v1/jobs/{job_id}"


@dataclass
class Profile:
    users: int = 20
    seconds: float = 60.0
    spawn_rate: float = 20.0
    job_size: str = "48x36"
    job_spp: int = 4
    session_size: str = "64x48"
    stop_timeout: float = 15.0

    def locust_args(self) -> list[str]:
        return [
            "-u", str(self.users), "-r", str(self.spawn_rate), "-t", f"{self.seconds:g}s",
            "--stop-timeout", f"{self.stop_timeout:g}",
            "--job-size", self.job_size, "--job-spp", str(self.job_spp),
            "--session-size", self.session_size,
        ]  # fmt: skip


@dataclass
class Chaos:
    """An action fired ``at`` seconds into the locust run (in a thread); ``note`` says what
    it did."""

    name: str
    at: float
    action: Callable[[], str]
    note: str = ""
    fired_at: float | None = None


@dataclass
class LoadRun:
    profile: Profile
    wall_seconds: float
    returncode: int
    endpoints: list[dict]
    counts: dict
    locust_jobs: dict
    chaos: Chaos | None = None
    server_status: dict = field(default_factory=dict)
    """The server's own timing of the status route during the run (``server_quantiles``)."""
    jobs: list[dict] = field(default_factory=list)
    results: dict = field(default_factory=dict)
    tracers: list[dict] = field(default_factory=list)

    @property
    def total(self) -> dict:
        return next(e for e in self.endpoints if e["name"] == "Aggregated")

    def endpoint(self, name: str) -> dict:
        return next(e for e in self.endpoints if e["name"] == name)

    @property
    def failures(self) -> int:
        return self.total["failures"]

    def job_counts(self) -> dict:
        statuses = [j["status"] for j in self.jobs]
        return {
            "submitted": len(self.jobs),
            "completed": statuses.count("done"),
            "failed": statuses.count("failed"),
            "cancelled": statuses.count("cancelled"),
            "unfinished": sum(s not in TERMINAL for s in statuses),
            "submitted (seen by locust)": self.counts.get("jobs submitted", 0),
        }

    def turnaround(self) -> dict:
        """Seconds from submission to the end of each completed job: p50, p95, max."""
        seconds = sorted(j["finished"] - j["created"] for j in self.jobs if j["status"] == "done")
        if not seconds:
            return {}
        p50, p95 = (seconds[min(len(seconds) - 1, int(q * len(seconds)))] for q in (0.5, 0.95))
        return {"p50": p50, "p95": p95, "max": seconds[-1]}

    def summary(self) -> dict:
        return {
            "server_status": self.server_status,
            "turnaround_seconds": self.turnaround(),
            "profile": self.profile.__dict__,
            "wall_seconds": self.wall_seconds,
            "endpoints": self.endpoints,
            "counts": self.counts,
            "jobs": self.job_counts(),
            "results": self.results,
            "chaos": None
            if self.chaos is None
            else {"name": self.chaos.name, "at": self.chaos.fired_at, "note": self.chaos.note},
        }


def run_profile(
    url: str, profile: Profile, out_dir: Path, chaos: Chaos | None = None, timeout: float = 600
) -> LoadRun:
    """Run the locust profile against ``url`` (and ``chaos`` part-way through)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    results_file = out_dir / "locust-results.json"
    command = [
        sys.executable, "-m", "locust", "-f", str(LOCUSTFILE), "--headless", "--host", url,
        *profile.locust_args(), "--csv", str(out_dir / "locust"), "--only-summary",
        "--loglevel", "WARNING", "--results-file", str(results_file),
    ]  # fmt: skip
    before = route_buckets(url, STATUS_ROUTE)
    started = time.monotonic()
    with open(out_dir / "locust.log", "wb") as log:
        process = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT, cwd=REPO_ROOT)
    thread = None
    if chaos is not None:
        thread = threading.Thread(target=_fire, args=(chaos, started), daemon=True)
        thread.start()
    try:
        returncode = process.wait(timeout)
    except subprocess.TimeoutExpired:
        process.kill()
        raise
    wall = time.monotonic() - started
    if thread is not None:
        thread.join(60)
    if not results_file.exists():
        log = (out_dir / "locust.log").read_text()
        raise RuntimeError(f"locust wrote no results: {log[-3000:]}")
    payload = json.loads(results_file.read_text())
    server_status = server_quantiles(before, route_buckets(url, STATUS_ROUTE))
    return LoadRun(
        profile=profile,
        wall_seconds=wall,
        returncode=returncode,
        endpoints=read_stats(out_dir / "locust_stats.csv"),
        counts=payload["counts"],
        locust_jobs=payload["jobs"],
        chaos=chaos,
        server_status=server_status,
    )


def _fire(chaos: Chaos, started: float) -> None:
    time.sleep(max(0.0, chaos.at - (time.monotonic() - started)))
    chaos.fired_at = time.monotonic() - started
    chaos.note = chaos.action()


def read_stats(path: Path) -> list[dict]:
    """Locust's ``*_stats.csv``: one row per endpoint, times in ms."""
    rows = []
    with open(path, newline="") as f:
        for row in csv.DictReader(f):
            rows.append(
                {
                    "type": row["Type"],
                    "name": row["Name"],
                    "requests": int(row["Request Count"]),
                    "failures": int(row["Failure Count"]),
                    "rps": float(row["Requests/s"]),
                    "p50": _ms(row["50%"]),
                    "p95": _ms(row["95%"]),
                    "p99": _ms(row["99%"]),
                    "max": _ms(row["Max Response Time"]),
                }
            )
    return rows


def _ms(text: str) -> float | None:
    return None if text in ("", "N/A") else float(text)


def route_buckets(url: str, route: str) -> dict[float, float]:
    """The server's own time-to-first-byte histogram of ``route`` (cumulative counts by upper
    bound in seconds), from /metrics."""
    from prometheus_client.parser import text_string_to_metric_families

    text = httpx.get(url + "/metrics", timeout=30).text
    buckets = {}
    for family in text_string_to_metric_families(text):
        if family.name != "tilerender_http_request_seconds":
            continue
        for sample in family.samples:
            label = sample.labels.get("route", "")
            # The service labels routes of nested routers without their /v1 prefix.
            if sample.name.endswith("_bucket") and route in (label, "/v1" + label):
                buckets[float(sample.labels["le"])] = sample.value
    return buckets


def server_quantiles(before: dict, after: dict, quantiles=(0.5, 0.95, 0.99)) -> dict:
    """Upper bounds (ms) of the server-side quantiles between two ``route_buckets`` readings:
    the smallest bucket bound below which that share of the requests answered."""
    counts = {le: after.get(le, 0) - before.get(le, 0) for le in sorted(after)}
    total = counts.get(float("inf"), 0)
    out = {"requests": total}
    for q in quantiles:
        bound = next((le for le, n in counts.items() if total and n >= q * total), None)
        out[f"p{round(q * 100)}_le_ms"] = None if bound is None else 1000 * bound
    return out


def list_jobs(http: httpx.Client) -> list[dict]:
    """Every job on the server (pages of 500)."""
    jobs, offset = [], 0
    while True:
        page = http.get("/v1/jobs", params={"limit": 500, "offset": offset}).json()["data"]
        jobs.extend(page)
        if len(page) < 500:
            return jobs
        offset += 500


def settle(http: httpx.Client, timeout: float = 300.0) -> list[dict]:
    """Wait until no job is queued or running; return them all."""
    deadline = time.monotonic() + timeout
    while True:
        jobs = list_jobs(http)
        if all(j["status"] in TERMINAL for j in jobs):
            return jobs
        if time.monotonic() > deadline:
            waiting = [j["id"] for j in jobs if j["status"] not in TERMINAL]
            raise TimeoutError(f"{len(waiting)} jobs still unfinished: {waiting[:5]}")
        time.sleep(0.5)


class References:
    """Local renders of the load scenes, one per distinct request (cached)."""

    def __init__(self) -> None:
        self.cache: dict[tuple, np.ndarray] = {}
        self.states: dict[str, object] = {}

    def image(self, scene_key: str, request: dict) -> np.ndarray:
        import dataclasses

        from tracer.compiled.scene import compile_scene
        from tracer.render import render_image
        from tracer.scene import format as fmt
        from tracer.scene.loader import load_scene

        key = (scene_key, *(request.get(k) for k in ("width", "height", "spp", "seed")))
        if key not in self.cache:
            if scene_key not in self.states:
                self.states[scene_key] = load_scene(SCENE_FILES[scene_key])
            state = self.states[scene_key]
            camera = fmt.override(
                state.camera, width=request.get("width"), height=request.get("height")
            )
            render = fmt.override(
                state.render,
                spp=request.get("spp"),
                seed=request.get("seed"),
                max_depth=request.get("max_depth"),
            )
            state = dataclasses.replace(state, camera=camera, render=render)
            self.cache[key] = render_image(compile_scene(state))[0]
        return self.cache[key]


def check_results(
    http: httpx.Client, jobs: list[dict], known: dict[str, dict], references: References
) -> dict:
    """Every done job's NPY result against its reference. A job's scene is the one locust
    recorded for it (``known``: id -> {"scene": key}), else the server's scene name (scenes
    may be deleted by then: such a job counts as ``unverified``)."""
    mismatched, unverified, checked = [], [], 0
    names: dict[str, str | None] = {}
    for job in jobs:
        if job["status"] != "done":
            continue
        key = known.get(job["id"], {}).get("scene")
        if key is None:
            scene_id = job["scene_id"]
            if scene_id not in names:
                r = http.get(f"/v1/scenes/{scene_id}")
                names[scene_id] = r.json()["name"] if r.status_code == 200 else None
            key = SCENE_NAMES.get(names[scene_id] or "")
        if key is None:
            unverified.append(job["id"])
            continue
        r = http.get(f"/v1/jobs/{job['id']}/result", params={"format": "npy"})
        r.raise_for_status()
        image = np.load(io.BytesIO(r.content))
        expected = references.image(key, job["request"])
        checked += 1
        if image.dtype != expected.dtype or not np.array_equal(image, expected):
            mismatched.append(job["id"])
    return {
        "checked": checked,
        "equal": checked - len(mismatched),
        "mismatched": mismatched,
        "unverified": unverified,
        "references": len(references.cache),
    }


def upload(http: httpx.Client, key: str) -> str:
    """Upload a load scene (as the locustfile does); returns its id."""
    path = SCENE_FILES[key]
    if key == "cornell":
        files = [("scene", ("scene.json", path.read_bytes(), "application/json"))]
        meshes = sorted(path.parent.glob("*.obj"))
        files += [("files", (m.name, m.read_bytes(), "text/plain")) for m in meshes]
        r = http.post("/v1/scenes", files=files, data={"name": "load-cornell"})
    else:
        r = http.post(
            "/v1/scenes",
            params={"name": f"load-{key}"},
            content=path.read_bytes(),
            headers={"content-type": "application/json"},
        )
    r.raise_for_status()
    return r.json()["id"]


def warm_up(http: httpx.Client, timeout: float = 900.0) -> dict:
    """One job per load scene and one session frame, before any timing: the first use of a
    kernel compiles it (minutes on a cold cache); returns the seconds each took."""
    seconds = {}
    for key in SCENE_FILES:
        scene_id = upload(http, key)
        start = time.monotonic()
        job = http.post(
            "/v1/jobs", json={"scene_id": scene_id, "width": 48, "height": 36, "spp": 4}
        ).json()
        while http.get(f"/v1/jobs/{job['id']}").json()["status"] not in TERMINAL:
            if time.monotonic() - start > timeout:
                raise TimeoutError(f"warm-up job on {key} did not finish")
            time.sleep(0.2)
        seconds[f"job {key}"] = time.monotonic() - start
    start = time.monotonic()
    session = http.post("/v1/sessions", json={"scene_id": scene_id, "width": 64, "height": 48})
    session.raise_for_status()
    frame_url = f"/v1/sessions/{session.json()['id']}/frame.jpg"
    while http.get(frame_url, params={"after": 0}, timeout=60).status_code != 200:
        if time.monotonic() - start > timeout:
            raise TimeoutError("warm-up session showed no frame")
    seconds["session frame"] = time.monotonic() - start
    http.delete(f"/v1/sessions/{session.json()['id']}")
    return seconds


def kill_a_tracer(url: str) -> str:
    """SIGKILL the process of a ready tracer (its pid from /v1/cluster): a chaos action."""
    tracers = httpx.get(url + "/v1/cluster", timeout=30).json()["tracers"]
    victim = next(t for t in reversed(tracers) if t["state"] == "ready" and t["pid"])
    os.kill(victim["pid"], signal.SIGKILL)
    return f"SIGKILL to tracer {victim['id']} (pid {victim['pid']})"


def tracer_failures(url: str) -> int:
    """Failures the coordinator counted over all tracers."""
    tracers = httpx.get(url + "/v1/cluster", timeout=30).json()["tracers"]
    return sum(t["failures"] for t in tracers)


def probe_full_queue(http: httpx.Client, scene_id: str, max_queue: int, probes: int = 20) -> dict:
    """Fill the queue with long jobs (``max_queue`` of them), then time ``probes`` more
    submissions, each of which must be a 429 with Retry-After; cancel the long jobs. A long
    job is an animation of many small frames: it holds its place in the queue for a long time
    but a cancel takes effect after the frame being rendered, within milliseconds."""
    poses = [
        {"position": [0.0, 0.0, 3.9 + 0.001 * i], "look_at": [0.0, 0.0, 2.9]} for i in range(500)
    ]
    slow = {
        "scene_id": scene_id,
        "kind": "animation",
        "camera_path": poses,
        "width": 32,
        "height": 24,
        "spp": 16,
    }
    filled = []
    for _ in range(max_queue * 2):
        r = http.post("/v1/jobs", json=slow)
        if r.status_code == 429:
            break
        assert r.status_code == 202, r.text
        filled.append(r.json()["id"])
    statuses, seconds, retry_after = [], [], set()
    for _ in range(probes):
        start = time.perf_counter()
        r = http.post("/v1/jobs", json=slow)
        seconds.append(time.perf_counter() - start)
        statuses.append(r.status_code)
        retry_after.add(r.headers.get("retry-after"))
    for job_id in filled:
        http.post(f"/v1/jobs/{job_id}/cancel")
    ordered = sorted(seconds)
    return {
        "queued_before_429": len(filled),
        "statuses": sorted(set(statuses)),
        "all_429": all(s == 429 for s in statuses),
        "retry_after": sorted(str(v) for v in retry_after),
        "p50_ms": 1000 * ordered[len(ordered) // 2],
        "max_ms": 1000 * ordered[-1],
        "cancelled": filled,
    }


def format_run(run: LoadRun) -> str:
    """The run as Markdown: one row per endpoint, then jobs, counters and result checks."""
    lines = [
        "| type | endpoint | requests | failures | req/s | p50 ms | p95 ms | p99 ms | max ms |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for e in run.endpoints:
        cells = [e["type"] or "all", e["name"], e["requests"], e["failures"], f"{e['rps']:.2f}"]
        cells += [_cell(e[k]) for k in ("p50", "p95", "p99", "max")]
        lines.append("| " + " | ".join(str(c) for c in cells) + " |")
    jobs = run.job_counts()
    lines.append("")
    lines.append("jobs: " + ", ".join(f"{k} {v}" for k, v in jobs.items()))
    lines.append("counters: " + ", ".join(f"{k} {v}" for k, v in sorted(run.counts.items())))
    if run.jobs and run.turnaround():
        t = run.turnaround()
        lines.append(
            f"job turnaround (submitted to done): p50 {t['p50']:.2f} s, p95 {t['p95']:.2f} s, "
            f"max {t['max']:.2f} s"
        )
    if run.server_status:
        s = run.server_status
        lines.append(
            f"status route timed by the server (time to first byte, histogram bucket bounds): "
            f"p50 <= {s['p50_le_ms']} ms, p95 <= {s['p95_le_ms']} ms, p99 <= {s['p99_le_ms']} ms "
            f"over {s['requests']:.0f} requests"
        )
    if run.results:
        r = run.results
        lines.append(
            f"results: {r['equal']} of {r['checked']} equal to their reference bit for bit "
            f"({r['references']} distinct references), mismatched {len(r['mismatched'])}, "
            f"unverified {len(r['unverified'])}"
        )
    if run.chaos is not None:
        at = "never" if run.chaos.fired_at is None else f"at {run.chaos.fired_at:.1f} s"
        lines.append(f"chaos: {run.chaos.name} {at}: {run.chaos.note}")
    lines.append(f"locust wall time {run.wall_seconds:.1f} s, exit code {run.returncode}")
    return "\n".join(lines)


def _cell(value: float | None) -> str:
    return "-" if value is None else f"{value:.0f}"


@contextlib.contextmanager
def service(workdir: Path, nodes: str = "embedded", tracers: int = 2):
    """A server to load: ``embedded`` (``tilerender serve --tracers N --threads 1``, its own
    Ray) or ``ray-start`` (a 0-CPU head, N one-CPU ``ray start`` workers and the API joined
    to the head: the compose shape). Yields ``(api, topology or None)``; stops everything."""
    from bench.load.topology import Topology, serve_embedded

    if nodes == "embedded":
        api = serve_embedded(workdir, workdir / "data", "--tracers", str(tracers), "--threads", "1")
        try:
            yield api, None
        finally:
            api.stop()
        return
    with Topology(workdir) as topology:
        topology.start_head(num_cpus=0)
        for _ in range(tracers):
            topology.add_worker(num_cpus=1)
        yield topology.start_api(workdir / "data"), topology


class CpuMeter:
    """CPU seconds (user + system) used by the API process, each tracer (pids from
    /v1/cluster at the start) and the whole machine, from construction to ``stop()``; the
    machine's share is what every process on it used, other people's included."""

    def __init__(self, api_pid: int, http: httpx.Client) -> None:
        import psutil

        tracers = http.get("/v1/cluster").json()["tracers"]
        self.processes = {"api": psutil.Process(api_pid)}
        self.processes.update({t["id"]: psutil.Process(t["pid"]) for t in tracers if t["pid"]})
        self.start = {name: self._seconds(p) for name, p in self.processes.items()}
        self.machine = self._machine()

    @staticmethod
    def _seconds(process) -> float | None:
        import psutil

        try:
            times = process.cpu_times()
        except psutil.Error:
            return None
        return times.user + times.system

    @staticmethod
    def _machine() -> float:
        import psutil

        times = psutil.cpu_times()
        return times.user + times.system + times.nice

    def stop(self) -> dict[str, float]:
        used = {}
        for name, process in self.processes.items():
            now = self._seconds(process)
            if now is not None and self.start[name] is not None:
                used[name] = now - self.start[name]
        used["machine (all processes)"] = self._machine() - self.machine
        return used

"""The service's latency: status while the cluster renders, camera update to streamed frame,
and the API's overhead per session frame.

Starts ``tilerender serve`` on 127.0.0.1 (a free port, a temporary data directory, its own
embedded Ray) and measures, over HTTP:

1. **Status p99 while rendering.** A long animation job renders (Cornell box, 320x240);
   ``--clients`` threads poll ``GET /v1/jobs/{id}`` as fast as they can for ``--seconds``;
   p50/p95/p99/max of the response times. Target: p99 <= 50 ms.
2. **Camera update -> first frame showing it.** A 320x180 session streams (MJPEG, read by a
   client thread); ``--updates`` camera moves, each ``PUT .../camera`` followed by waiting for
   frames. Reported: the server's measure (the update to the publication of the first frame
   rendered after it, from the session's stats) and the client's (the PUT to the arrival of
   the second frame after the PUT's answer: the frame in flight when the update arrived cannot
   show it, the next one does).
3. **API overhead per session frame at 320x180.** The render thread's time between two
   frames of the one session (bookkeeping, the hand-off to the JPEG encoder, calls,
   scheduling) against the frame's own render time (``InteractiveSession.render_next``);
   JPEG encoding runs on another thread and is reported separately. Target: <= 5 %.

    python bench/api_latency.py [--seconds 10] [--clients 4] [--updates 20]
"""

import argparse
import json
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from common import (
    REPO_ROOT,
    fmt_float,
    machine_info,
    print_machine,
    print_table,
    styled_verdict,
    verdict,
    write_results,
)

CORNELL = REPO_ROOT / "scenes" / "cornell-box"
TILERENDER = Path(sys.executable).with_name("tilerender")


def start_server(data_dir: Path, extra: list[str]) -> tuple[subprocess.Popen, str]:
    import httpx

    process = subprocess.Popen(
        [str(TILERENDER), "serve", "--port", "0", "--data-dir", str(data_dir), *extra],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
    )
    line = process.stdout.readline()
    if "viewer at" not in line:
        process.kill()
        raise SystemExit(f"tilerender serve did not start: {line!r}")
    url = line.split("viewer at", 1)[1].strip().split("#")[0].rstrip("/")
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline:
        try:
            if httpx.get(url + "/readyz", timeout=5).status_code == 200:
                return process, url
        except httpx.TransportError:
            pass
        time.sleep(0.2)
    process.kill()
    raise SystemExit("the server did not become ready")


def percentiles(values: list[float]) -> dict[str, float]:
    ordered = sorted(values)

    def at(q: float) -> float:
        return ordered[min(len(ordered) - 1, int(q * len(ordered)))]

    return {
        "n": len(ordered),
        "p50_ms": 1000 * at(0.5),
        "p95_ms": 1000 * at(0.95),
        "p99_ms": 1000 * at(0.99),
        "max_ms": 1000 * ordered[-1],
        "mean_ms": 1000 * statistics.fmean(ordered),
    }


def upload_cornell(http) -> str:
    fields = [("scene", ("scene.json", (CORNELL / "scene.json").read_bytes()))]
    for path in sorted(CORNELL.glob("*.obj")):
        fields.append(("files", (path.name, path.read_bytes())))
    response = http.post("/v1/scenes", files=fields)
    response.raise_for_status()
    return response.json()["id"]


def status_while_rendering(http, url: str, scene: str, seconds: float, clients: int) -> dict:
    import httpx

    path = [{"position": [0.2 * i, 0.0, 3.9], "look_at": [0.0, 0.0, 2.9]} for i in range(1000)]
    body = {"scene_id": scene, "kind": "animation", "spp": 16, "width": 320, "height": 240}
    job = http.post("/v1/jobs", json={**body, "camera_path": path}).json()
    while http.get(f"/v1/jobs/{job['id']}").json()["status"] != "running":
        time.sleep(0.05)
    times: list[float] = []
    lock = threading.Lock()
    stop = time.monotonic() + seconds

    def poll() -> None:
        with httpx.Client(base_url=url, timeout=30) as client:
            while time.monotonic() < stop:
                start = time.perf_counter()
                client.get(f"/v1/jobs/{job['id']}").raise_for_status()
                with lock:
                    times.append(time.perf_counter() - start)

    threads = [threading.Thread(target=poll) for _ in range(clients)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    status = http.get(f"/v1/jobs/{job['id']}").json()
    http.post(f"/v1/jobs/{job['id']}/cancel")
    return {**percentiles(times), "frames_rendered": status["progress"]["frames_done"]}


class StreamReader(threading.Thread):
    """Reads a session's MJPEG stream, recording each frame's arrival time."""

    def __init__(self, url: str):
        super().__init__(daemon=True)
        self.url = url
        self.arrivals: list[float] = []
        self.stopped = False

    def run(self) -> None:
        import httpx

        with httpx.Client(timeout=60) as client, client.stream("GET", self.url) as response:
            buffer = b""
            for chunk in response.iter_bytes():
                buffer += chunk
                while True:
                    head = buffer.find(b"\r\n\r\n")
                    if head < 0:
                        break
                    headers = dict(
                        line.split(": ", 1)
                        for line in buffer[:head].decode().split("\r\n")[1:]
                        if ": " in line
                    )
                    end = head + 4 + int(headers["Content-Length"]) + 2
                    if len(buffer) < end:
                        break
                    self.arrivals.append(time.perf_counter())
                    buffer = buffer[end:]
                if self.stopped:
                    return


def session_latency(http, url: str, scene: str, updates: int, warm: float) -> dict:
    session = http.post(
        "/v1/sessions", json={"scene_id": scene, "width": 320, "height": 180}
    ).json()
    reader = StreamReader(url + session["stream_url"])
    reader.start()
    time.sleep(warm)  # the session's workload scaler settles on its frame rate
    client_latency = []
    for k in range(updates):
        angle = 0.05 * (k + 1)
        camera = {"position": [angle, 0.0, 3.9], "look_at": [0.0, 0.0, 2.9]}
        sent = time.perf_counter()
        http.put(f"/v1/sessions/{session['id']}/camera", json=camera).raise_for_status()
        answered = time.perf_counter()
        while sum(1 for a in reader.arrivals if a > answered) < 2:
            time.sleep(0.001)
        second = [a for a in reader.arrivals if a > answered][1]
        client_latency.append(second - sent)
        time.sleep(0.2)
    stats = http.get(f"/v1/sessions/{session['id']}").json()["stats"]
    reader.stopped = True
    http.delete(f"/v1/sessions/{session['id']}")
    return {
        "client": percentiles(client_latency),
        "server_mean_ms": stats["camera_latency_ms"],
        "fps": stats.get("fps"),
        "fps_stream": stats.get("fps_stream"),
        "spp": stats.get("spp"),
        "scale": stats.get("scale"),
        "render_ms": stats["render_ms"],
        "api_overhead_ms": stats["api_overhead_ms"],
        "api_overhead_percent": stats["api_overhead_percent"],
        "encode_ms": stats["encode_ms"],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=10.0, help="status polling time")
    parser.add_argument("--clients", type=int, default=4, help="concurrent status pollers")
    parser.add_argument("--updates", type=int, default=20, help="camera updates to time")
    parser.add_argument("--warm", type=float, default=3.0, help="session warm-up seconds")
    parser.add_argument("--tracers", type=int, default=None, help="tracers (default: one)")
    parser.add_argument("--threads", type=int, default=None, help="CPUs per tracer")
    args = parser.parse_args()

    import httpx

    machine = machine_info()
    print_machine(machine)
    extra = ["--tracers", str(args.tracers)] if args.tracers else []
    extra += ["--threads", str(args.threads)] if args.threads else []
    with tempfile.TemporaryDirectory() as data:
        process, url = start_server(Path(data), extra)
        try:
            http = httpx.Client(base_url=url, timeout=60)
            scene = upload_cornell(http)
            status = status_while_rendering(http, url, scene, args.seconds, args.clients)
            session = session_latency(http, url, scene, args.updates, args.warm)
        finally:
            process.send_signal(signal.SIGINT)
            try:
                process.wait(30)
            except subprocess.TimeoutExpired:
                process.kill()

    p99_verdict = verdict(status["p99_ms"], 50.0, at_most=True)
    overhead = session["api_overhead_percent"]
    overhead_verdict = "-" if overhead is None else verdict(overhead, 5.0, at_most=True)
    print_table(
        f"GET /v1/jobs/{{id}} while a 320x240 animation renders ({args.clients} clients)",
        ["requests", "p50 ms", "p95 ms", "p99 ms", "max ms", "frames", "p99 <= 50 ms"],
        [[status["n"], fmt_float(status["p50_ms"]), fmt_float(status["p95_ms"]),
          fmt_float(status["p99_ms"]), fmt_float(status["max_ms"]),
          status["frames_rendered"], styled_verdict(p99_verdict)]],
    )  # fmt: skip
    client = session["client"]
    print_table(
        "Session 320x180: camera update -> first frame showing it",
        ["measure", "mean ms", "p50 ms", "p95 ms", "max ms"],
        [
            ["server (update -> frame published)", fmt_float(session["server_mean_ms"]),
             "-", "-", "-"],
            ["client (PUT -> 2nd frame after it)", fmt_float(client["mean_ms"]),
             fmt_float(client["p50_ms"]), fmt_float(client["p95_ms"]), fmt_float(client["max_ms"])],
        ],
    )  # fmt: skip
    print_table(
        "Session 320x180: API overhead per frame",
        ["render ms", "overhead ms", "overhead %", "JPEG ms (other thread)", "fps", "spp",
         "<= 5 %"],
        [[fmt_float(session["render_ms"]), fmt_float(session["api_overhead_ms"], 3),
          fmt_float(overhead), fmt_float(session["encode_ms"]),
          fmt_float(session["fps_stream"], 1), session["spp"], styled_verdict(overhead_verdict)]],
    )  # fmt: skip
    write_results(
        "api_latency",
        {
            "options": vars(args),
            "status_while_rendering": {**status, "verdict": p99_verdict},
            "session": {**session, "overhead_verdict": overhead_verdict},
        },
        machine,
    )
    if os.environ.get("BENCH_PRINT_JSON"):
        print(json.dumps({"status": status, "session": session}, indent=2))


if __name__ == "__main__":
    main()

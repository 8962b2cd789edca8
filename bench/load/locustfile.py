"""Locust users for tilerender's service: a realistic mix against a real server.

    locust -f bench/load/locustfile.py --headless --host http://127.0.0.1:PORT \\
        -u 20 -r 20 -t 60s --csv OUT/load --results-file OUT/results.json

Three kinds of user (the mix of a 20-user run in brackets):

- ``JobUser`` (the rest: 15 of 20): uploads a scene (the Cornell box as multipart with its
  meshes, or the many-lights scene as raw JSON; every ``UPLOAD_EVERY`` jobs a fresh upload,
  and the previous scene is deleted),
  submits a small still (``--job-size``, ``--job-spp``, a seed from ``SEEDS``), follows it by
  polling ``GET /v1/jobs/{id}`` (two users in three) or its Server-Sent Events (one in three),
  then downloads the result as NPY (and now and then as PNG). One job at a time per user, so
  the queue never holds more jobs than there are job users (keep them below ``MAX_QUEUE``).
- ``ViewerUser`` (3): opens an interactive session (``--session-size``) and cycles: reads
  frames from the MJPEG stream, sends a camera update (an orbit step), reads more frames,
  asks for the session's stats; every few cycles closes the session and opens another.
- ``BrowseUser`` (2): the cluster page, job and scene lists, health, readiness and metrics.

Streams are read on connections of their own (geventhttpclient), reported to locust as
``STREAM`` entries: the SSE stream's time to its first event and the MJPEG stream's time to
its first frame. A 429 (full queue or session table) is backpressure, not an error: it is
counted (``rejected``) and the user waits ``Retry-After``; every other status >= 400 and
every broken stream is a failure. At the end the file named by ``--results-file`` gets the
counters: jobs submitted (ids), jobs seen done, frames streamed, camera updates, sessions.
"""

import json
import math
import random
import threading
import time
from collections import Counter
from pathlib import Path

from geventhttpclient import HTTPClient
from locust import FastHttpUser, between, events, task

REPO_ROOT = Path(__file__).resolve().parents[2]
CORNELL = REPO_ROOT / "scenes" / "cornell-box"
MANY_LIGHTS = REPO_ROOT / "scenes" / "many-lights" / "scene.json"
SEEDS = (0, 1, 2, 3)
UPLOAD_EVERY = 5
"""A job user uploads a fresh scene every this many jobs."""
SESSION_CYCLES = 4
"""A viewer closes its session and opens another after this many cycles."""
FRAMES_PER_READ = 3
TERMINAL = ("done", "failed", "cancelled")
STREAM_TIMEOUT = 60.0

COUNTS: Counter = Counter()
JOBS: dict[str, dict] = {}
_lock = threading.Lock()


@events.init_command_line_parser.add_listener
def _options(parser) -> None:
    parser.add_argument("--results-file", default="", help="JSON counters written at the end")
    parser.add_argument("--job-size", default="48x36", help="WIDTHxHEIGHT of the jobs")
    parser.add_argument("--job-spp", type=int, default=4, help="samples per pixel of the jobs")
    parser.add_argument("--session-size", default="64x48", help="WIDTHxHEIGHT of the sessions")
    parser.add_argument("--poll-interval", type=float, default=0.25, help="status polling, s")


@events.test_stop.add_listener
def _write_results(environment, **_kw) -> None:
    path = environment.parsed_options.results_file
    if path:
        with _lock:
            payload = {"counts": dict(COUNTS), "jobs": JOBS}
        Path(path).write_text(json.dumps(payload, indent=1))


def size(text: str) -> tuple[int, int]:
    width, height = text.lower().split("x")
    return int(width), int(height)


def scene_upload() -> tuple[str, dict]:
    """A scene to upload: ``(key, request kwargs)`` for locust's client."""
    if random.random() < 0.5:
        scene = (CORNELL / "scene.json").read_bytes()
        files = [("scene", ("scene.json", scene, "application/json"))]
        for mesh in sorted(CORNELL.glob("*.obj")):
            files.append(("files", (mesh.name, mesh.read_bytes(), "text/plain")))
        return "cornell", {"files": files, "data": {"name": "load-cornell"}}
    return "many-lights", {
        "url": "/v1/scenes?name=load-many-lights",
        "data": MANY_LIGHTS.read_bytes(),
        "headers": {"Content-Type": "application/json"},
    }


class Stream:
    """A streaming GET on a connection of its own; reports to locust as a ``STREAM`` entry."""

    def __init__(self, user: FastHttpUser, path: str, name: str):
        self.user, self.path, self.name = user, path, name
        self.client = HTTPClient.from_url(
            user.host, connection_timeout=10, network_timeout=STREAM_TIMEOUT
        )
        self.started = time.perf_counter()
        self.response = self.client.get(path)

    def report(self, length: int, exception: Exception | None = None) -> None:
        self.user.environment.events.request.fire(
            request_type="STREAM",
            name=self.name,
            response_time=(time.perf_counter() - self.started) * 1000,
            response_length=length,
            exception=exception,
            context={},
        )

    def close(self) -> None:
        self.client.close()


def ok(response, name: str) -> bool:
    """Mark a response (``catch_response``): 429 counts as backpressure, >= 400 fails."""
    if response.status_code == 429:
        COUNTS[f"rejected {name}"] += 1
        response.success()
        return False
    if response.status_code >= 400 or response.status_code == 0:
        response.failure(f"{response.status_code}: {response.text[:200] if response.text else ''}")
        return False
    response.success()
    return True


def retry_after(response) -> float:
    try:
        return float(response.headers.get("Retry-After", 1))
    except (TypeError, ValueError):
        return 1.0


class JobUser(FastHttpUser):
    """Uploads scenes, submits small stills, follows them, downloads the results."""

    weight = 1
    wait_time = between(0.2, 1.0)

    def on_start(self) -> None:
        self.scene_id = None
        self.jobs_since_upload = 0
        self.follow_events = random.random() < 1 / 3

    def upload(self) -> bool:
        """Upload a fresh scene and delete the previous one (its jobs keep their copy)."""
        key, kwargs = scene_upload()
        url = kwargs.pop("url", "/v1/scenes")
        with self.client.post(url, name="/v1/scenes", catch_response=True, **kwargs) as response:
            if not ok(response, "upload"):
                return False
            previous, self.scene_id, self.scene_key = self.scene_id, response.json()["id"], key
        COUNTS["scenes uploaded"] += 1
        self.jobs_since_upload = 0
        if previous is not None:
            with self.client.delete(
                f"/v1/scenes/{previous}", name="/v1/scenes/[id]", catch_response=True
            ) as response:
                if ok(response, "delete scene"):
                    COUNTS["scenes deleted"] += 1
        return True

    @task
    def render_one(self) -> None:
        if (self.scene_id is None or self.jobs_since_upload >= UPLOAD_EVERY) and not self.upload():
            return
        width, height = size(self.environment.parsed_options.job_size)
        body = {
            "scene_id": self.scene_id,
            "kind": "still",
            "width": width,
            "height": height,
            "spp": self.environment.parsed_options.job_spp,
            "seed": random.choice(SEEDS),
        }
        with self.client.post("/v1/jobs", json=body, name="/v1/jobs", catch_response=True) as r:
            if not ok(r, "job"):
                if r.status_code == 429:
                    time.sleep(retry_after(r))
                return
            job_id = r.json()["id"]
        self.jobs_since_upload += 1
        with _lock:
            JOBS[job_id] = {"scene": self.scene_key, "request": body, "seen": None}
        COUNTS["jobs submitted"] += 1
        status = self.follow_sse(job_id) if self.follow_events else self.poll(job_id)
        JOBS[job_id]["seen"] = status
        if status != "done":
            return
        COUNTS["jobs seen done"] += 1
        fmt = "png" if random.random() < 0.2 else "npy"
        with self.client.get(
            f"/v1/jobs/{job_id}/result?format={fmt}",
            name=f"/v1/jobs/[id]/result?format={fmt}",
            catch_response=True,
        ) as r:
            if ok(r, "result") and fmt == "npy" and not r.content.startswith(b"\x93NUMPY"):
                r.failure("not an NPY file")

    def poll(self, job_id: str) -> str | None:
        interval = self.environment.parsed_options.poll_interval
        while True:
            with self.client.get(
                f"/v1/jobs/{job_id}", name="/v1/jobs/[id]", catch_response=True
            ) as r:
                if not ok(r, "status"):
                    return None
                status = r.json()["status"]
            if status in TERMINAL:
                return status
            time.sleep(interval)

    def follow_sse(self, job_id: str) -> str | None:
        stream = Stream(self, f"/v1/jobs/{job_id}/events", "/v1/jobs/[id]/events (first event)")
        try:
            if stream.response.status_code != 200:
                stream.report(0, RuntimeError(f"status {stream.response.status_code}"))
                return None
            event, reported, length = None, False, 0
            while True:
                line = stream.response.readline(b"\n")
                if not line:
                    stream.report(length, RuntimeError("the event stream ended early"))
                    return None
                length += len(line)
                text = line.decode().strip()
                if text.startswith("event: "):
                    event = text[7:]
                    COUNTS["events received"] += 1
                    if not reported:
                        stream.report(length)
                        reported = True
                    if event in ("done", "error", "cancelled"):
                        return {"done": "done", "error": "failed"}.get(event, event)
        except Exception as error:  # a broken stream is a failure of this request
            stream.report(0, error)
            return None
        finally:
            stream.close()


class ViewerUser(FastHttpUser):
    """An interactive session: stream frames, move the camera, read stats."""

    fixed_count = 3
    wait_time = between(0.1, 0.5)

    def on_start(self) -> None:
        self.session_id = None
        self.cycles = 0
        self.angle = random.uniform(0, 2 * math.pi)
        with self.client.post(
            "/v1/scenes?name=load-many-lights",
            data=MANY_LIGHTS.read_bytes(),
            headers={"Content-Type": "application/json"},
            name="/v1/scenes",
            catch_response=True,
        ) as r:
            self.scene_id = r.json()["id"] if ok(r, "upload") else None
        self.camera = None

    def on_stop(self) -> None:
        self.close_session()
        if self.scene_id is not None:
            with self.client.delete(
                f"/v1/scenes/{self.scene_id}", name="/v1/scenes/[id]", catch_response=True
            ) as r:
                ok(r, "delete scene")

    def open_session(self) -> bool:
        width, height = size(self.environment.parsed_options.session_size)
        body = {"scene_id": self.scene_id, "width": width, "height": height}
        with self.client.post(
            "/v1/sessions", json=body, name="/v1/sessions", catch_response=True
        ) as r:
            if not ok(r, "session"):
                if r.status_code == 429:
                    time.sleep(retry_after(r))
                return False
            session = r.json()
        self.session_id, self.cycles = session["id"], 0
        self.camera = session["camera"]
        COUNTS["sessions opened"] += 1
        return True

    def close_session(self) -> None:
        if self.session_id is None:
            return
        with self.client.delete(
            f"/v1/sessions/{self.session_id}", name="/v1/sessions/[id]", catch_response=True
        ) as r:
            ok(r, "close")
        self.session_id = None

    @task
    def view(self) -> None:
        if self.scene_id is None:
            return
        if self.session_id is None and not self.open_session():
            return
        self.read_frames(FRAMES_PER_READ)
        self.move_camera()
        self.read_frames(FRAMES_PER_READ)
        with self.client.get(
            f"/v1/sessions/{self.session_id}", name="/v1/sessions/[id]", catch_response=True
        ) as r:
            if ok(r, "session stats"):
                COUNTS["server frames streamed (last seen)"] = r.json()["stats"].get(
                    "frames_streamed", 0
                )
        self.cycles += 1
        if self.cycles >= SESSION_CYCLES:
            self.close_session()

    def move_camera(self) -> None:
        self.angle += 0.3
        position = self.camera["position"]
        look_at = self.camera["look_at"]
        dx, dz = position[0] - look_at[0], position[2] - look_at[2]
        radius = math.hypot(dx, dz)
        pose = {
            "position": [
                look_at[0] + radius * math.sin(self.angle),
                position[1],
                look_at[2] + radius * math.cos(self.angle),
            ],
            "look_at": look_at,
        }
        with self.client.put(
            f"/v1/sessions/{self.session_id}/camera",
            json=pose,
            name="/v1/sessions/[id]/camera",
            catch_response=True,
        ) as r:
            if ok(r, "camera"):
                COUNTS["camera updates"] += 1

    def read_frames(self, count: int) -> None:
        """Read ``count`` JPEG parts of the MJPEG stream (multipart/x-mixed-replace)."""
        stream = Stream(
            self, f"/v1/sessions/{self.session_id}/stream", "/v1/sessions/[id]/stream (first frame)"
        )
        try:
            response = stream.response
            if response.status_code != 200:
                stream.report(0, RuntimeError(f"status {response.status_code}"))
                return
            length = 0
            for index in range(count):
                headers = {}
                line = response.readline()
                while line in (b"\r\n",):  # the CRLF after the previous part
                    line = response.readline()
                if line.strip() != b"--frame":
                    raise RuntimeError(f"expected a part boundary, got {line[:40]!r}")
                while (line := response.readline()) not in (b"\r\n", b""):
                    name, _, value = line.decode().partition(":")
                    headers[name.strip().lower()] = value.strip()
                jpeg = response.read(int(headers["content-length"]))
                if not jpeg.startswith(b"\xff\xd8"):
                    raise RuntimeError("a part is not a JPEG")
                length += len(jpeg)
                COUNTS["frames streamed"] += 1
                if index == 0:
                    stream.report(length)
        except Exception as error:
            stream.report(0, error)
        finally:
            stream.close()


class BrowseUser(FastHttpUser):
    """Someone looking around: cluster, lists, health and metrics."""

    fixed_count = 2
    wait_time = between(0.5, 2.0)

    @task(3)
    def cluster(self) -> None:
        self.client.get("/v1/cluster")

    @task(3)
    def jobs(self) -> None:
        self.client.get("/v1/jobs?limit=20", name="/v1/jobs?limit=20")

    @task(1)
    def scenes(self) -> None:
        self.client.get("/v1/scenes")

    @task(1)
    def health(self) -> None:
        self.client.get("/healthz")
        self.client.get("/readyz")

    @task(1)
    def metrics(self) -> None:
        self.client.get("/metrics")

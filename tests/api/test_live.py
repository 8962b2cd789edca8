"""Against a real server: ``tilerender serve`` on 127.0.0.1 in a subprocess (uvicorn, its own
embedded Ray). Upload -> job -> result is bit-identical to ``tilerender render`` of the same
scene and settings; the MJPEG stream shows changing frames, and a commit during a session
shows in it; Server-Sent Events arrive as the job renders."""

import io
import json
import subprocess
import time

import httpx
import numpy as np
from PIL import Image

from tests.api.conftest import TILERENDER, cornell_files, tiny_json
from tests.helpers import CORNELL


def wait_done(http: httpx.Client, job_id: str, timeout: float = 120.0) -> dict:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        job = http.get(f"/v1/jobs/{job_id}").json()
        if job["status"] in ("done", "failed", "cancelled"):
            return job
        time.sleep(0.05)
    raise TimeoutError(job)


def test_upload_job_result_equals_the_cli(live_server, tmp_path):
    http = httpx.Client(base_url=live_server.url, timeout=60)
    scene = http.post("/v1/scenes", files=cornell_files()).json()
    flags = {"spp": 4, "width": 64, "height": 48, "seed": 3}
    job = http.post("/v1/jobs", json={"scene_id": scene["id"], **flags}).json()
    job = wait_done(http, job["id"])
    assert job["status"] == "done", job
    api_npy = np.load(io.BytesIO(http.get(f"/v1/jobs/{job['id']}/result?format=npy").content))
    api_png = http.get(f"/v1/jobs/{job['id']}/result?format=png").content
    args = [arg for k, v in flags.items() for arg in (f"--{k}", str(v))]
    for out in ("cli.npy", "cli.png"):
        subprocess.run(
            [str(TILERENDER), "render", str(CORNELL), "-o", str(tmp_path / out), *args, "-q"],
            check=True,
            timeout=300,
        )
    cli_npy = np.load(tmp_path / "cli.npy")
    assert api_npy.dtype == cli_npy.dtype == np.float32
    assert np.array_equal(api_npy, cli_npy)  # every bit
    png = np.asarray(Image.open(io.BytesIO(api_png)))
    assert np.array_equal(png, np.asarray(Image.open(tmp_path / "cli.png")))


class Parts:
    """Reads the parts of a multipart/x-mixed-replace stream: ``next(count)`` returns the
    (headers, jpeg) of the next ``count`` frames."""

    def __init__(self, response) -> None:
        self.chunks = response.iter_bytes()
        self.buffer = b""

    def next(self, count: int = 1, timeout: float = 60.0) -> list[tuple[dict, bytes]]:
        parts = []
        deadline = time.monotonic() + timeout
        while len(parts) < count:
            assert time.monotonic() < deadline, "no frames"
            buffer = self.buffer
            head_end = buffer.find(b"\r\n\r\n")
            if buffer.startswith(b"--frame\r\n") and head_end > 0:
                lines = buffer[9:head_end].decode().split("\r\n")
                headers = dict(line.split(": ", 1) for line in lines)
                end = head_end + 4 + int(headers["Content-Length"])
                if len(buffer) >= end + 2:
                    parts.append((headers, buffer[head_end + 4 : end]))
                    self.buffer = buffer[end + 2 :]
                    continue
            self.buffer += next(self.chunks)
        return parts


def pixels(jpeg: bytes) -> np.ndarray:
    return np.asarray(Image.open(io.BytesIO(jpeg)).convert("RGB"), np.float64)


def test_stream_shows_frames_and_commits(live_server):
    http = httpx.Client(base_url=live_server.url, timeout=60)
    scene = http.post("/v1/scenes", files={"scene": ("s.json", tiny_json())}).json()
    session = http.post(
        "/v1/sessions", json={"scene_id": scene["id"], "width": 64, "height": 48}
    ).json()
    with http.stream("GET", session["stream_url"]) as response:
        assert response.headers["content-type"] == "multipart/x-mixed-replace; boundary=frame"
        stream = Parts(response)
        parts = stream.next(3)
        images = [pixels(jpeg) for _, jpeg in parts]
        before = images[-1].mean((0, 1))
        assert all(image.mean() > 1.0 for image in images)  # not black
        assert len({jpeg for _, jpeg in parts}) == 3  # changing
        ops = [{"op": "set_material", "name": "grey", "material": {"reflectance": [0.9, 0.0, 0.0]}}]
        committed = time.perf_counter()
        assert (
            http.post(f"/v1/scenes/{scene['id']}/commits", json={"ops": ops}).json()["version"] == 1
        )
        seen_version = None
        for _ in range(200):  # the session blends the change in over a few frames
            headers, jpeg = stream.next()[0]
            if headers["X-Frame-Version"] == "1":
                seen_version = seen_version or time.perf_counter() - committed
                after = pixels(jpeg).mean((0, 1))
                if after[1] < 0.9 * before[1] and after[0] > after[1] + 5:
                    break
        shown = time.perf_counter() - committed
        assert seen_version is not None and seen_version < 10.0
        assert after[1] < 0.9 * before[1] and after[0] > after[1] + 5, (after, before)
        assert shown < 30.0
    stats = http.get(f"/v1/sessions/{session['id']}").json()["stats"]
    assert stats["frames_streamed"] >= 4
    assert http.delete(f"/v1/sessions/{session['id']}").status_code == 204


def test_events_over_http(live_server):
    http = httpx.Client(base_url=live_server.url, timeout=60)
    scene = http.post(
        "/v1/scenes", content=tiny_json(), headers={"content-type": "application/json"}
    ).json()
    job = http.post(
        "/v1/jobs", json={"scene_id": scene["id"], "spp": 8, "width": 32, "height": 24}
    ).json()
    kinds = []
    with http.stream("GET", f"/v1/jobs/{job['id']}/events") as response:
        for line in response.iter_lines():
            if line.startswith("event: "):
                kinds.append(line[7:])
                if kinds[-1] in ("done", "error", "cancelled"):
                    break
            elif line.startswith("data: "):
                json.loads(line[6:])
    assert kinds[0] == "status" and kinds[-1] == "done"
    assert http.get("/metrics").text.count("tilerender_jobs_total") >= 1

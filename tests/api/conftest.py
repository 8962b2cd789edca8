"""Fixtures of the API tests: one embedded Ray for the whole run, apps on temporary data
directories, a live ``tilerender serve`` on 127.0.0.1, and small scenes to upload.

Test apps render with one tracer of one CPU, so two apps (the restart test's second, or a
module's own next to a shared one) fit on the two-CPU embedded Ray together."""

import contextlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.helpers import CORNELL, tiny_scene, zip_bytes  # noqa: F401 (tests import it here)

TILERENDER = Path(sys.executable).with_name("tilerender")
READY_TIMEOUT = 300.0


def make_settings(data_dir: Path, **changes):
    from api.settings import Settings

    values = {
        "data_dir": data_dir,
        "tracers": 1,
        "threads": 1,
        "request_timeout": 60.0,
    }
    values.update(changes)
    return Settings(**values)


@pytest.fixture(scope="session")
def ray_session():
    """One embedded Ray (2 CPUs) for every in-process app of the run."""
    from cluster.connect import connect, disconnect

    connection = connect(num_cpus=2)
    yield connection
    if connection.started:
        disconnect()


def wait_ready(client, timeout: float = READY_TIMEOUT) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        r = client.get("/readyz")
        if r.status_code == 200:
            return
        if r.json().get("status") == "failed":
            raise RuntimeError(r.json()["message"])
        time.sleep(0.1)
    raise TimeoutError("the service did not become ready")


@contextlib.contextmanager
def app_client(data_dir: Path, ready: bool = True, **changes):
    """A TestClient on a fresh app (lifespan entered; waits for /readyz)."""
    from fastapi.testclient import TestClient

    from api.app import create_app

    app = create_app(make_settings(data_dir, **changes))
    with TestClient(app, raise_server_exceptions=False) as client:
        if ready:
            wait_ready(client)
        yield client


@pytest.fixture(scope="module")
def client(ray_session, tmp_path_factory):
    """A ready app shared by a module's tests."""
    with app_client(tmp_path_factory.mktemp("api")) as c:
        yield c


@pytest.fixture
def settings_of():
    """Change a client's settings for one test (restored afterwards)."""
    changed = []

    def change(client, **values):
        settings = client.app.state.settings
        for key, value in values.items():
            changed.append((settings, key, getattr(settings, key)))
            setattr(settings, key, value)

    yield change
    for settings, key, value in reversed(changed):
        setattr(settings, key, value)


# --- Scenes to upload ---------------------------------------------------------------------


def cornell_files() -> list:
    """Multipart fields uploading the Cornell box: its JSON and every mesh it names."""
    folder = CORNELL.parent
    fields = [("scene", ("scene.json", CORNELL.read_bytes(), "application/json"))]
    for path in sorted(folder.glob("*.obj")):
        fields.append(("files", (path.name, path.read_bytes(), "text/plain")))
    return fields


def tiny_json(**changes) -> bytes:
    return json.dumps(tiny_scene(**changes)).encode()


def animated_scene(frames: int = 4) -> dict:
    scene = tiny_scene()
    scene["objects"][1]["kind"] = "rigid"
    scene["animation"] = {
        "fps": 4,
        "frames": frames,
        "objects": {"cube": [{"time": 0}, {"time": 1, "translate": [1, 0.5, 0]}]},
        "camera": [{"time": 0}, {"time": 1, "position": [1, 1.5, 4]}],
    }
    return scene


def upload_tiny(client, **changes) -> dict:
    r = client.post("/v1/scenes", files={"scene": ("scene.json", tiny_json(**changes))})
    assert r.status_code == 201, r.text
    return r.json()


def upload_json(client, scene: dict) -> dict:
    r = client.post("/v1/scenes", files={"scene": ("scene.json", json.dumps(scene).encode())})
    assert r.status_code == 201, r.text
    return r.json()


def wait_job(client, job_id: str, timeout: float = 120.0, statuses=("done", "failed", "cancelled")):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        r = client.get(f"/v1/jobs/{job_id}")
        assert r.status_code == 200, r.text
        if r.json()["status"] in statuses:
            return r.json()
        time.sleep(0.05)
    raise TimeoutError(f"job {job_id} still {r.json()['status']}")


# --- A live server --------------------------------------------------------------------------


class LiveServer:
    def __init__(self, process: subprocess.Popen, url: str, data_dir: Path):
        self.process = process
        self.url = url.rstrip("/")
        self.data_dir = data_dir

    def stop(self, timeout: float = 30.0) -> int:
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGINT)
            try:
                self.process.wait(timeout)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait(10)
        return self.process.returncode


def start_server(data_dir: Path, *extra: str, env: dict | None = None) -> LiveServer:
    """``tilerender serve --port 0`` in a subprocess (its own embedded Ray); waits for
    /readyz."""
    import httpx

    environ = {**os.environ, **(env or {})}
    process = subprocess.Popen(
        [str(TILERENDER), "serve", "--port", "0", "--data-dir", str(data_dir), *extra],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=environ,
        cwd=Path(__file__).resolve().parents[2],
    )
    line = process.stdout.readline()
    if "viewer at" not in line:
        process.kill()
        raise RuntimeError(f"serve did not start: {line!r} {process.stderr.read()[-2000:]}")
    url = line.split("viewer at", 1)[1].strip().split("#")[0]
    server = LiveServer(process, url, data_dir)
    deadline = time.monotonic() + READY_TIMEOUT
    while time.monotonic() < deadline:
        try:
            if httpx.get(server.url + "/readyz", timeout=5).status_code == 200:
                return server
        except httpx.TransportError:
            pass
        if process.poll() is not None:
            raise RuntimeError(f"serve exited: {process.stderr.read()[-2000:]}")
        time.sleep(0.2)
    server.stop()
    raise TimeoutError("the live server did not become ready")


@pytest.fixture(scope="module")
def live_server(tmp_path_factory):
    server = start_server(tmp_path_factory.mktemp("live"), "--tracers", "1", "--threads", "1")
    yield server
    server.stop()

"""The HTTP side of docker/smoke-test.sh (standard library only, so any Python 3.11 runs it).

Against a running service: wait until it is ready with the expected number of tracers, upload a
scene directory (its scene.json and mesh files), submit a still job, run ``--kill`` (a command,
e.g. ``docker kill CONTAINER``) once the job has rendered for ``--kill-after`` seconds, wait for
the job to finish, and save its result as NPY. Prints one JSON line with the timings and the
cluster's view of its tracers after the job; exits 1 with a message on any failure.

    python3 docker/smoke_client.py --url http://127.0.0.1:8000 --scene-dir scenes/cornell-box \
        --spp 256 --width 256 --height 256 --seed 3 --tracers 2 \
        --kill "docker kill abc123" --kill-after 3 --out api.npy
"""

import argparse
import json
import shlex
import subprocess
import sys
import time
import urllib.error
import urllib.request
import uuid
from pathlib import Path


class SmokeFailure(Exception):
    """The check failed; ``str()`` says how."""


class Client:
    def __init__(self, url: str, token: str | None) -> None:
        self.url = url.rstrip("/")
        self.headers = {"Authorization": f"Bearer {token}"} if token else {}

    def request(
        self, method: str, path: str, body: bytes | None = None, content_type: str | None = None
    ) -> tuple[int, bytes]:
        headers = dict(self.headers)
        if content_type:
            headers["Content-Type"] = content_type
        request = urllib.request.Request(self.url + path, body, headers, method=method)
        try:
            with urllib.request.urlopen(request, timeout=60) as response:
                return response.status, response.read()
        except urllib.error.HTTPError as error:
            return error.code, error.read()

    def json(self, method: str, path: str, payload: dict | None = None, expect: int = 200) -> dict:
        body = None if payload is None else json.dumps(payload).encode()
        status, data = self.request(method, path, body, "application/json" if body else None)
        if status != expect:
            raise SmokeFailure(f"{method} {path}: HTTP {status}, expected {expect}: {data[:300]!r}")
        return json.loads(data)


def multipart(fields: list[tuple[str, str, bytes]]) -> tuple[bytes, str]:
    """A multipart/form-data body of (field name, file name, content) parts, and its type."""
    boundary = uuid.uuid4().hex
    parts = []
    for name, filename, content in fields:
        head = (
            f"--{boundary}\r\nContent-Disposition: form-data; name={json.dumps(name)}; "
            f"filename={json.dumps(filename)}\r\nContent-Type: application/octet-stream\r\n\r\n"
        )
        parts.append(head.encode() + content + b"\r\n")
    parts.append(f"--{boundary}--\r\n".encode())
    return b"".join(parts), f"multipart/form-data; boundary={boundary}"


def wait_ready(client: Client, tracers: int, timeout: float) -> dict:
    deadline = time.monotonic() + timeout
    last = None
    while time.monotonic() < deadline:
        try:
            status, data = client.request("GET", "/readyz")
            last = data.decode(errors="replace")
            if status == 200 and json.loads(data).get("tracers", 0) >= tracers:
                return json.loads(data)
            if status == 503 and json.loads(data).get("status") == "failed":
                raise SmokeFailure(f"the service failed to start: {last}")
        except (urllib.error.URLError, ConnectionError, TimeoutError) as error:
            last = str(error)
        time.sleep(1)
    raise SmokeFailure(f"not ready with {tracers} tracers within {timeout:g} s (last: {last})")


def upload(client: Client, scene_dir: Path) -> str:
    fields = [("scene", "scene.json", (scene_dir / "scene.json").read_bytes())]
    for mesh in sorted(scene_dir.glob("*.obj")):
        fields.append(("files", mesh.name, mesh.read_bytes()))
    body, content_type = multipart(fields)
    status, data = client.request("POST", "/v1/scenes", body, content_type)
    if status != 201:
        raise SmokeFailure(f"upload of {scene_dir}: HTTP {status}: {data[:300]!r}")
    return json.loads(data)["id"]


def run_job(client: Client, args: argparse.Namespace, scene_id: str) -> dict:
    """Submit the job, kill once it has run for ``kill_after`` s, wait; returns the record."""
    request = {"scene_id": scene_id, "kind": "still", "spp": args.spp, "width": args.width}
    request |= {"height": args.height, "seed": args.seed}
    job = client.json("POST", "/v1/jobs", request, expect=202)
    submitted = time.monotonic()
    running_since = killed_at = None
    record: dict = {}
    while time.monotonic() - submitted < args.timeout:
        job = client.json("GET", f"/v1/jobs/{job['id']}")
        now = time.monotonic()
        if job["status"] in ("done", "failed", "cancelled"):
            break
        if job["status"] == "running" and running_since is None:
            running_since = now
        due = running_since is not None and now - running_since >= args.kill_after
        if args.kill and killed_at is None and due:
            subprocess.run(shlex.split(args.kill), check=True, capture_output=True, timeout=60)
            killed_at = time.monotonic()
            record["killed_after_seconds"] = round(killed_at - running_since, 2)
            record["progress_at_kill"] = job.get("progress")
        time.sleep(0.2)
    else:
        raise SmokeFailure(f"job {job['id']} did not finish within {args.timeout:g} s: {job}")
    if job["status"] != "done":
        raise SmokeFailure(f"job {job['id']} ended {job['status']}: {job.get('error')}")
    if args.kill and killed_at is None:
        raise SmokeFailure(
            f"job {job['id']} finished before the kill (after {args.kill_after:g} s of "
            "rendering): give it more work (--spp)"
        )
    finished = time.monotonic()
    record |= {
        "job": job["id"],
        "job_seconds": round(finished - submitted, 2),
        "after_kill_seconds": round(finished - killed_at, 2) if killed_at else None,
    }
    return record


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--url", required=True)
    parser.add_argument("--token")
    parser.add_argument("--scene-dir", type=Path, required=True)
    for name in ("spp", "width", "height", "seed", "tracers"):
        parser.add_argument(f"--{name}", type=int, required=True)
    parser.add_argument("--kill", help="command run once, mid-job (e.g. docker kill ID)")
    parser.add_argument("--kill-after", type=float, default=3.0, help="seconds into the job")
    parser.add_argument("--timeout", type=float, default=600.0, help="seconds per wait")
    parser.add_argument("--out", type=Path, required=True, help="the job's result (NPY)")
    args = parser.parse_args(argv)
    client = Client(args.url, args.token)
    try:
        ready = wait_ready(client, args.tracers, args.timeout)
        status, page = client.request("GET", "/")
        if status != 200 or b"<html" not in page.lower():
            raise SmokeFailure(f"the viewer at {args.url}/ answered HTTP {status}")
        scene_id = upload(client, args.scene_dir)
        record = {"ready": ready} | run_job(client, args, scene_id)
        status, data = client.request("GET", f"/v1/jobs/{record['job']}/result?format=npy")
        if status != 200:
            raise SmokeFailure(f"result of job {record['job']}: HTTP {status}: {data[:300]!r}")
        args.out.write_bytes(data)
        cluster = client.json("GET", "/v1/cluster")
        record["tracers_after"] = [
            {key: t.get(key) for key in ("id", "state", "failures", "node")}
            for t in cluster["tracers"]
        ]
    except (SmokeFailure, OSError, subprocess.SubprocessError) as error:
        print(f"smoke_client: FAILED: {error}", file=sys.stderr)
        return 1
    print(json.dumps(record))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

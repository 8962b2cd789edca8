"""The compose topology without Docker, in the test suite: a ``ray start --head`` process, a
``ray start --address`` worker process and ``tilerender serve --ray-address`` on this machine
(the entry points of the compose services, ``bench/load/topology.py``). A job renders through
them, on tracers of both nodes, and equals a local render bit for bit; afterwards no process
of the topology is left."""

import io
import time

import httpx
import numpy as np
import psutil

from bench.load.harness import References, upload
from bench.load.topology import Topology

JOB = {"width": 64, "height": 48, "spp": 4, "seed": 3}


def wait_done(http: httpx.Client, job_id: str, timeout: float = 300.0) -> dict:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        job = http.get(f"/v1/jobs/{job_id}").json()
        if job["status"] in ("done", "failed", "cancelled"):
            return job
        time.sleep(0.1)
    raise TimeoutError(job)


def test_a_job_renders_through_head_worker_and_api(tmp_path):
    pids: set[int] = set()
    with Topology(tmp_path) as topology:
        head = topology.start_head(num_cpus=1)
        worker = topology.add_worker(num_cpus=1)
        api = topology.start_api(tmp_path / "data")
        http = httpx.Client(base_url=api.url, timeout=60)

        tracers = http.get("/v1/cluster").json()["tracers"]
        assert [t["state"] for t in tracers] == ["ready", "ready"], tracers
        assert len({t["node"] for t in tracers}) == 2  # one tracer per node (the default)
        by_node = {t["pid"] for t in tracers}
        assert by_node & head.pids() and by_node & worker.pids()  # each under its ray start

        scene_id = upload(http, "cornell")
        job = http.post("/v1/jobs", json={"scene_id": scene_id, **JOB})
        assert job.status_code == 202, job.text
        job = wait_done(http, job.json()["id"])
        assert job["status"] == "done", (job, api.log_tail())
        result = http.get(f"/v1/jobs/{job['id']}/result", params={"format": "npy"})
        image = np.load(io.BytesIO(result.content))
        assert np.array_equal(image, References().image("cornell", JOB))  # every bit

        last = http.get("/v1/cluster").json()["last_frame"]
        lines = {tracer: info["lines"] for tracer, info in last["tracers"].items()}
        assert sorted(lines) == ["t0", "t1"] and all(n > 0 for n in lines.values()), last
        pids = head.pids() | worker.pids() | {api.process.pid}
    assert api.process.returncode == 0, api.log_tail()  # a clean shutdown on SIGINT
    deadline = time.monotonic() + 10
    while (left := [p for p in pids if running(p)]) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not left, "processes of the topology are still running"


def running(pid: int) -> bool:
    try:
        return psutil.Process(pid).status() != psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return False

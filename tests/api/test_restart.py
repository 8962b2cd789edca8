"""Nothing is lost on restart: finished results stay downloadable, unfinished jobs resume at
their first frame without a result (and render exactly what an uninterrupted job renders),
or are marked failed with the reason; scenes come back at their committed version."""

import json
import time

from tests.api.conftest import animated_scene, app_client, wait_job


def wait_frames(client, job_id: str, count: int, timeout: float = 120.0) -> dict:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        job = client.get(f"/v1/jobs/{job_id}").json()
        if job["progress"]["frames_done"] >= count:
            return job
        time.sleep(0.02)
    raise TimeoutError(job)


def test_restart_keeps_results_and_resumes_jobs(ray_session, tmp_path):
    data = tmp_path / "data"
    scene_json = json.dumps(animated_scene(frames=24)).encode()
    with app_client(data) as c:
        scene = c.post("/v1/scenes", files={"scene": ("a.json", scene_json)}).json()
        move = {"op": "set_sky", "radiance": [0.05, 0.05, 0.05]}
        assert (
            c.post(f"/v1/scenes/{scene['id']}/commits", json={"ops": [move]}).json()["version"] == 1
        )
        still = c.post("/v1/jobs", json={"scene_id": scene["id"], "spp": 2}).json()
        still = wait_job(c, still["id"])
        before = c.get(f"/v1/jobs/{still['id']}/result?format=npy").content
        body = {"scene_id": scene["id"], "kind": "animation", "spp": 16, "width": 48, "height": 32}
        long = c.post("/v1/jobs", json=body).json()
        queued = c.post("/v1/jobs", json={**body, "frames": [0, 1]}).json()
        done_before = wait_frames(c, long["id"], 3)["progress"]["frames_done"]
    # The app stopped in the middle of the long job (the thread finished its frame).
    with app_client(data) as c:
        assert c.get(f"/v1/scenes/{scene['id']}").json()["version"] == 1
        after = c.get(f"/v1/jobs/{still['id']}/result?format=npy")
        assert after.status_code == 200 and after.content == before
        job = c.get(f"/v1/jobs/{long['id']}").json()
        assert job["resumed"] == 1 and job["progress"]["frames_done"] >= done_before
        job = wait_job(c, long["id"])
        assert job["status"] == "done" and [f["frame"] for f in job["frames"]] == list(range(24))
        assert wait_job(c, queued["id"])["status"] == "done"
        # A resumed frame is bit-identical to the same frame of an uninterrupted job.
        fresh = c.post("/v1/jobs", json={**body, "frames": [22]}).json()
        wait_job(c, fresh["id"])
        a = c.get(f"/v1/jobs/{long['id']}/frames/22?format=npy").content
        b = c.get(f"/v1/jobs/{fresh['id']}/frames/22?format=npy").content
        assert a == b
        # Leave one unfinished for the next start.
        unfinished = c.post("/v1/jobs", json=body).json()
        wait_frames(c, unfinished["id"], 1)
    with app_client(data, resume_jobs=False) as c:
        job = c.get(f"/v1/jobs/{unfinished['id']}").json()
        assert job["status"] == "failed"
        assert "restarted" in job["error"]
        assert c.get(f"/v1/jobs/{unfinished['id']}/frames/0?format=png").status_code == 200
        listed = c.get("/v1/jobs").json()
        assert {j["id"] for j in listed["data"]} >= {still["id"], long["id"], unfinished["id"]}

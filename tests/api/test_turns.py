"""Jobs render in bounded turns (``api.job_run``, ``cluster.turns``): however small the turns,
a job's image is the whole frame's bit for bit; while a big job renders, queries, queued jobs
and cancels get the render thread within about a turn; progress moves with every turn; a
queued job knows its place."""

import io
import time

import numpy as np
import pytest

from tests.api.conftest import tiny_json, upload_tiny, wait_job
from tracer.compiled.scene import compile_scene
from tracer.render import render_image
from tracer.scene import format as fmt
from tracer.scene.loader import load_scene


@pytest.fixture
def frame_regions(monkeypatch):
    """The region of every coordinator frame this process renders during the test."""
    from cluster.coordinator import Coordinator

    regions = []
    render = Coordinator.render_frame

    def counted(self, request=None, graph=None):
        regions.append(None if request is None else request.region)
        return render(self, request, graph)

    monkeypatch.setattr(Coordinator, "render_frame", counted)
    return regions


def small_turns(monkeypatch, samples: int) -> None:
    """Every turn takes ``samples`` samples, whatever the measured rate (so the cut does not
    depend on this machine's speed)."""
    from cluster.turns import TurnSizer

    monkeypatch.setattr(TurnSizer, "samples", lambda _self: samples)


def result_of(client, job_id: str) -> np.ndarray:
    return np.load(io.BytesIO(client.get(f"/v1/jobs/{job_id}/result?format=npy").content))


def test_a_job_in_many_turns_is_the_whole_frame_bit_for_bit(
    client, frame_regions, tmp_path, monkeypatch
):
    small_turns(monkeypatch, 1000)  # 15 pixels of a 40-pixel line at 64 spp
    scene = upload_tiny(client)
    body = {"scene_id": scene["id"], "spp": 64, "width": 40, "height": 30}
    job = wait_job(client, client.post("/v1/jobs", json=body).json()["id"])
    assert job["status"] == "done", job
    assert len(frame_regions) > 10 and any(r and r[1] - r[0] < 40 for r in frame_regions)
    assert job["progress"]["samples_done"] == 40 * 30 * 64
    path = tmp_path / "scene.json"
    path.write_bytes(tiny_json())
    state = load_scene(path)
    camera = fmt.override(state.camera, width=40, height=30)
    expected = render_image(compile_scene(state), camera, fmt.override(state.render, spp=64))[0]
    assert np.array_equal(result_of(client, job["id"]), expected)


def test_a_progressive_job_in_many_turns_equals_one_in_few(
    client, settings_of, frame_regions, monkeypatch
):
    """Parts and spot checks in tiny runs: the same waves, estimate and image bits."""
    scene = upload_tiny(client)
    body = {"scene_id": scene["id"], "target_error": 0.2, "width": 32, "height": 24}
    settings_of(client, job_turn_seconds=10.0)
    results = []
    for samples in (None, 200):
        if samples is not None:
            small_turns(monkeypatch, samples)
        frame_regions.clear()
        job = wait_job(client, client.post("/v1/jobs", json=body).json()["id"])
        assert job["status"] == "done", job
        results.append((job["frames"][0], result_of(client, job["id"]), len(frame_regions)))
    (few, image_few, runs_few), (many, image_many, runs_many) = results
    assert runs_many > 2 * runs_few
    assert (many["spp"], many["error_estimate"]) == (few["spp"], few["error_estimate"])
    assert np.array_equal(image_many, image_few)


def test_a_big_job_leaves_the_render_thread_to_others_and_cancel_stops_it(client, settings_of):
    """A job of minutes (one frame): progress moves while it runs, a ray query answers, queued
    jobs know their place, and after its cancel a small job is done within seconds."""
    settings_of(client, job_turn_seconds=0.2)
    scene = upload_tiny(client)
    query = {"origin": [0, 5, 0.1], "direction": [0, -1, 0]}
    assert client.post(f"/v1/scenes/{scene['id']}/query", json=query).status_code == 200  # warm
    big = {"scene_id": scene["id"], "spp": 4096, "width": 256, "height": 256}
    big_id = client.post("/v1/jobs", json=big).json()["id"]
    deadline = time.monotonic() + 60
    while True:
        status = client.get(f"/v1/jobs/{big_id}").json()
        if status["status"] == "running" and status["progress"]["samples_done"] > 0:
            break
        assert time.monotonic() < deadline, status
        time.sleep(0.05)
    first = status["progress"]["samples_done"]
    start = time.monotonic()
    r = client.post(f"/v1/scenes/{scene['id']}/query", json=query)
    assert r.status_code == 200 and r.json()["hit"], r.text
    assert time.monotonic() - start < 5.0
    small = {"scene_id": scene["id"], "spp": 1, "width": 8, "height": 8}
    queued = [client.post("/v1/jobs", json=small).json()["id"] for _ in range(2)]
    positions = [client.get(f"/v1/jobs/{j}").json()["queue_position"] for j in queued]
    assert positions == [0, 1]
    later = client.get(f"/v1/jobs/{big_id}").json()["progress"]
    assert later["samples_done"] > first and later["eta_seconds"] is not None
    assert client.post(f"/v1/jobs/{queued[0]}/cancel").status_code == 200
    assert client.get(f"/v1/jobs/{queued[1]}").json()["queue_position"] == 0
    cancelled = time.monotonic()
    assert client.post(f"/v1/jobs/{big_id}/cancel").status_code == 200
    done = wait_job(client, queued[1], timeout=15.0)
    assert done["status"] == "done" and time.monotonic() - cancelled < 15.0
    final = client.get(f"/v1/jobs/{big_id}").json()
    assert final["status"] == "cancelled" and final["progress"]["frames_done"] == 0


def test_a_waves_arithmetic_runs_off_the_render_thread():
    """A progressive frame's heavy numpy (estimate, spot-check plan) runs on the wave worker:
    the render thread's turn gives way while it runs, and gets its result."""
    import threading

    from api.job_run import off_thread

    release = threading.Event()

    def slow() -> str:
        release.wait(10)
        return threading.current_thread().name

    turns = off_thread(slow)
    next(turns)  # not done within a turn's wait: the render thread is free for others
    release.set()
    with pytest.raises(StopIteration) as done:
        while True:
            next(turns)
    assert done.value.value.startswith("tilerender-waves")

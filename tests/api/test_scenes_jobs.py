"""Scenes and jobs through the test client: upload (JSON with files, zip bundle, one mesh
file, a JSON body), inspect, commit, query, delete; stills and animations by spp, target
error and time budget; progress, events, cancel, results in three formats."""

import io
import json
import os
import signal
import time

import numpy as np
import pytest
from PIL import Image

from tests.api.conftest import (
    animated_scene,
    cornell_files,
    tiny_json,
    upload_json,
    upload_tiny,
    wait_job,
    zip_bytes,
)
from tests.helpers import GLTF_BOX, SCENES, tiny_scene
from tracer.compiled.scene import compile_scene
from tracer.render import render_image
from tracer.scene.loader import load_scene


def test_health_ready_metrics_openapi(client):
    assert client.get("/healthz").json() == {"status": "ok"}
    ready = client.get("/readyz")
    assert ready.status_code == 200 and ready.json()["tracers"] == 1
    doc = client.get("/openapi.json").json()
    assert "/v1/scenes" in doc["paths"] and "/v1/jobs/{job_id}/events" in doc["paths"]
    metrics = client.get("/metrics")
    assert metrics.status_code == 200
    assert "tilerender_http_requests_total" in metrics.text
    assert "tilerender_tracers_ready 1.0" in metrics.text


def test_upload_json_with_files_and_inspect(client):
    r = client.post("/v1/scenes", files=cornell_files())
    assert r.status_code == 201, r.text
    scene = r.json()
    assert r.headers["location"] == f"/v1/scenes/{scene['id']}"
    assert scene["source"] == "json" and scene["version"] == 0
    assert scene["triangles"] == 36
    assert scene["bounds"]["min"] == pytest.approx([-1, -1.01, -1], abs=1e-6)
    plan = scene["effects"]  # the tracers' own effect plan for this scene
    assert {"area_lights", "light_samples", "shadows", "indirect"} <= set(plan["effects"])
    assert {"sky", "refraction", "point_lights"} <= set(plan["skipped"])
    assert plan["reasons"]["refraction"] == "no dielectric"
    assert client.get(f"/v1/scenes/{scene['id']}").json()["triangles"] == 36
    glass = {"type": "dielectric", "ior": 1.5}
    r = client.post(
        f"/v1/scenes/{scene['id']}/commits",
        json={"ops": [{"op": "set_material", "name": "white", "material": glass}]},
    )
    assert r.status_code == 200, r.text
    after = client.get(f"/v1/scenes/{scene['id']}").json()["effects"]
    assert {"refraction", "specular"} <= set(after["effects"])  # the plan follows commits
    listed = client.get("/v1/scenes").json()
    assert scene["id"] in [s["id"] for s in listed["data"]]
    metrics = client.get("/metrics").text  # requests are labelled by their full route template
    assert 'method="POST",route="/v1/scenes/{scene_id}/commits",status="200"' in metrics
    assert 'method="GET",route="/readyz",status="200"' in metrics


def test_upload_bundle_mesh_and_json_body(client):
    bundle = zip_bytes({"scene.json": tiny_json(), "extra/readme.txt": b"hello"})
    r = client.post("/v1/scenes", files={"bundle": ("scene.zip", bundle, "application/zip")})
    assert r.status_code == 201, r.text
    assert r.json()["source"] == "bundle" and r.json()["name"] == "scene"
    r = client.post("/v1/scenes", content=bundle, headers={"content-type": "application/zip"})
    assert r.status_code == 201, r.text
    r = client.post("/v1/scenes", files={"mesh": ("Box.gltf", GLTF_BOX.read_bytes())})
    assert r.status_code == 201, r.text
    assert r.json()["source"] == "mesh" and r.json()["triangles"] == 12 + 2  # box + light
    r = client.post("/v1/scenes", content=tiny_json(), headers={"content-type": "application/json"})
    assert r.status_code == 201, r.text


def test_commit_versions_and_all_or_nothing(client):
    scene = upload_tiny(client)
    url = f"/v1/scenes/{scene['id']}"
    move = {"op": "set_transform", "node": "cube", "transform": {"translate": [0.3, 0.5, 0]}}
    r = client.post(url + "/commits", json={"ops": [move]})
    assert r.json() == {"scene_id": scene["id"], "version": 1}
    r = client.patch(url, json={"ops": [{"op": "set_sky", "radiance": [0.1, 0.1, 0.1]}]})
    assert r.json()["version"] == 2
    bad = [move, {"op": "set_transform", "node": "nope", "transform": {}}]
    r = client.post(url + "/commits", json={"ops": bad})
    assert r.status_code == 422 and "nope" in r.json()["error"]["message"]
    detail = client.get(url).json()
    assert detail["version"] == 2 and detail["sky"] == [0.1, 0.1, 0.1]


def test_query_ray_and_pixel(client):
    scene = upload_tiny(client)
    url = f"/v1/scenes/{scene['id']}/query"
    r = client.post(url, json={"origin": [0, 5, 0.1], "direction": [0, -1, 0]})
    assert r.status_code == 200, r.text
    hit = r.json()
    assert hit["hit"] and hit["node_name"] == "lamp" and hit["distance"] == pytest.approx(2.0)
    r = client.post(url, json={"x": 6, "y": 7.5})  # bottom centre of the 12x8 image: the floor
    assert r.json()["hit"] and r.json()["node_name"] == "floor", r.json()
    r = client.post(url, json={"origin": [0, 5, 0], "direction": [0, 1, 0]})
    assert r.json()["hit"] is False
    # After a commit the query sees the new version.
    ops = [{"op": "remove_node", "node": "lamp"}]
    assert client.post(f"/v1/scenes/{scene['id']}/commits", json={"ops": ops}).status_code == 200
    r = client.post(url, json={"origin": [0, 5, 0.1], "direction": [0, -1, 0]})
    assert r.json()["node_name"] == "cube" and r.json()["version"] == 1


def test_delete_scene(client):
    scene = upload_tiny(client)
    assert client.delete(f"/v1/scenes/{scene['id']}").status_code == 204
    assert client.get(f"/v1/scenes/{scene['id']}").status_code == 404
    assert client.delete(f"/v1/scenes/{scene['id']}").status_code == 404


def test_still_job_equals_render_image_and_formats(client, tmp_path):
    scene = upload_tiny(client)
    r = client.post("/v1/jobs", json={"scene_id": scene["id"], "spp": 3, "width": 16, "height": 10})
    assert r.status_code == 202, r.text
    job = wait_job(client, r.json()["id"])
    assert job["status"] == "done", job
    assert job["progress"]["frames_done"] == 1 and job["frames"][0]["spp"] == 3
    npy = np.load(io.BytesIO(client.get(f"/v1/jobs/{job['id']}/result?format=npy").content))
    path = tmp_path / "scene.json"
    path.write_bytes(tiny_json())
    state = load_scene(path)
    from tracer.scene import format as fmt

    camera = fmt.override(state.camera, width=16, height=10)
    settings = fmt.override(state.render, spp=3)
    expected = render_image(compile_scene(state), camera, settings)[0]
    assert npy.dtype == np.float32 and np.array_equal(npy, expected)
    png = client.get(f"/v1/jobs/{job['id']}/frames/0?format=png")
    assert png.headers["content-type"] == "image/png"
    assert Image.open(io.BytesIO(png.content)).size == (16, 10)
    exr = client.get(f"/v1/jobs/{job['id']}/result?format=exr")
    assert exr.status_code == 200 and exr.content[:4] == b"\x76\x2f\x31\x01"


def test_job_kernel_choice_same_pixels_and_bad_kernel_refused(client):
    """A job may name the kernel: the stream kernel's frame is the single-ray kernel's, bit for
    bit, through the cluster; the frame metadata says which ran; an unknown kernel is a 422
    naming the field, and no job is made."""
    scene = upload_tiny(client)
    frames = {}
    for kernel in ("single", "stream"):
        body = {"scene_id": scene["id"], "spp": 2, "width": 12, "height": 8, "kernel": kernel}
        r = client.post("/v1/jobs", json=body)
        assert r.status_code == 202, r.text
        job = wait_job(client, r.json()["id"])
        assert job["status"] == "done", job
        frames[kernel] = client.get(f"/v1/jobs/{job['id']}/result?format=npy").content
    assert frames["single"] == frames["stream"]
    jobs_before = client.get("/v1/jobs").json()["count"]
    r = client.post("/v1/jobs", json={"scene_id": scene["id"], "kernel": "gpu"})
    assert r.status_code == 422 and "kernel" in r.text
    assert client.get("/v1/jobs").json()["count"] == jobs_before


def test_job_light_sampler(client):
    """A job may name the light sampler, and it reaches the tracers: the tiny scene's frame by
    the light tree is a real image and not the power sampler's bits (the same seed, other
    light picks); an unknown sampler is a 422 naming the field."""
    scene = upload_tiny(client)
    frames = {}
    for sampler in ("power", "tree"):
        body = {"scene_id": scene["id"], "spp": 2, "width": 12, "height": 8}
        r = client.post("/v1/jobs", json={**body, "light_sampler": sampler})
        assert r.status_code == 202, r.text
        job = wait_job(client, r.json()["id"])
        assert job["status"] == "done", job
        content = client.get(f"/v1/jobs/{job['id']}/result?format=npy").content
        frames[sampler] = np.load(io.BytesIO(content))
    assert frames["tree"].max() > 0.0 and np.isfinite(frames["tree"]).all()
    assert frames["tree"].tobytes() != frames["power"].tobytes()
    r = client.post("/v1/jobs", json={"scene_id": scene["id"], "light_sampler": "bvh"})
    assert r.status_code == 422 and "light_sampler" in r.text


def test_job_layers_aovs_and_denoise(client, tmp_path):
    """A job with aovs and denoise: its frame's default image is the denoised layer, ?layer=
    gives each layer, format=npz and a multilayer exr hold every layer with the same bits and
    the names of the ids, and the beauty is the plain job's; a layer the frame lacks is a 404,
    a bad denoise value or AOVs with a first-hit integrator a 422 (and no job is made)."""
    from tracer.io.layers import layer_as_rgb, read_layers

    scene = upload_tiny(client)
    base = {"scene_id": scene["id"], "spp": 2, "width": 12, "height": 8}
    plain = wait_job(client, client.post("/v1/jobs", json=base).json()["id"])
    r = client.post("/v1/jobs", json={**base, "aovs": True, "denoise": "fast"})
    assert r.status_code == 202, r.text
    job = wait_job(client, r.json()["id"])
    assert job["status"] == "done", job
    url = f"/v1/jobs/{job['id']}/frames/0"
    bundle = tmp_path / "frame.npz"
    bundle.write_bytes(client.get(f"{url}?format=npz").content)
    layers, metadata = read_layers(bundle)
    aovs = ["albedo", "normal", "depth", "position", "alpha", "object_id", "material_id"]
    assert list(layers) == ["beauty", "denoised", *aovs]
    assert metadata["denoise"]["quality"] == "fast"
    objects, materials = {"0": "floor", "1": "cube", "2": "lamp"}, {"0": "grey", "1": "lamp"}
    assert metadata["ids"] == {"object_id": objects, "material_id": materials}
    exr = tmp_path / "frame.exr"
    exr.write_bytes(client.get(f"{url}?format=exr").content)
    from_exr, _ = read_layers(exr)
    assert all(np.array_equal(from_exr[n], layers[n]) for n in layers)
    beauty = np.load(io.BytesIO(client.get(f"/v1/jobs/{plain['id']}/result?format=npy").content))
    assert np.array_equal(layers["beauty"], beauty)
    default = np.load(io.BytesIO(client.get(f"{url}?format=npy").content))
    assert np.array_equal(default, layers["denoised"])
    for name in ("beauty", "albedo", "depth", "object_id", "material_id"):
        shown = np.load(io.BytesIO(client.get(f"{url}?format=npy&layer={name}").content))
        assert np.array_equal(shown, layer_as_rgb(layers, name, view=False)), name
    for name in ("normal", "object_id"):
        assert client.get(f"{url}?format=png&layer={name}").status_code == 200
    assert client.get(f"/v1/jobs/{plain['id']}/frames/0?format=png").status_code == 200
    r = client.get(f"/v1/jobs/{plain['id']}/frames/0?format=png&layer=albedo")
    assert r.status_code == 404 and "no albedo layer" in r.text
    jobs_before = client.get("/v1/jobs").json()["count"]
    for bad in ({"denoise": "best"}, {"aovs": True, "kernel": "stream"}):
        r = client.post("/v1/jobs", json={**base, **bad})
        assert r.status_code == 422, r.text
    assert client.get("/v1/jobs").json()["count"] == jobs_before


def test_a_denoised_job_to_a_target_error_says_which_image_it_estimated(client, tmp_path):
    """A job with a target error and denoising: past 16 samples per part its waves take the
    denoised image's estimate, and the stored frame says so; ``denoise_prefilter`` reaches the
    denoiser."""
    from tracer.io.layers import read_layers

    scene = upload_tiny(client)
    body = {"scene_id": scene["id"], "width": 24, "height": 16, "target_error": 1e-4}
    body |= {"max_spp": 128, "denoise": "fast", "denoise_prefilter": "on"}
    r = client.post("/v1/jobs", json=body)
    assert r.status_code == 202, r.text
    job = wait_job(client, r.json()["id"])
    assert job["status"] == "done", job
    bundle = tmp_path / "frame.npz"
    bundle.write_bytes(client.get(f"/v1/jobs/{job['id']}/frames/0?format=npz").content)
    layers, metadata = read_layers(bundle)
    assert "denoised" in layers and metadata["denoise"]["prefiltered"] is True
    assert metadata["error_of"] == "denoised"


def test_a_job_chooses_adaptive_sampling(client, tmp_path):
    """``adaptive`` on a job by target error reaches its frames (their metadata has the mean
    samples per pixel and the adaptive waves, as do their events); on a job by spp it is a
    422."""
    from tracer.io.layers import read_layers

    scene = upload_tiny(client)
    body = {"scene_id": scene["id"], "width": 24, "height": 16, "target_error": 1e-4}
    body |= {"aovs": True}  # a bundle of layers, which keeps the metadata
    for adaptive, waves in ((False, 0), ("on", None)):
        r = client.post("/v1/jobs", json=body | {"max_spp": 64, "adaptive": adaptive})
        assert r.status_code == 202, r.text
        job = wait_job(client, r.json()["id"])
        assert job["status"] == "done", job
        bundle = tmp_path / "frame.npz"
        bundle.write_bytes(client.get(f"/v1/jobs/{job['id']}/frames/0?format=npz").content)
        _, metadata = read_layers(bundle)
        assert metadata["mean_spp"] <= 64
        if waves is not None:
            assert metadata["adaptive_waves"] == waves and metadata["mean_spp"] == 64
    r = client.post("/v1/jobs", json={"scene_id": scene["id"], "spp": 2, "adaptive": "on"})
    assert r.status_code == 422 and "adaptive applies" in r.text


def test_textured_bundle_renders_like_the_library(client):
    """The textured sample scene uploaded as a bundle (JSON, GLB, OBJ, MTL, PNGs) renders
    through the cluster exactly as the library renders it: its images and UVs reach the
    tracers in the snapshot."""
    folder = SCENES / "textured"
    files = [p for p in sorted(folder.iterdir()) if p.suffix not in (".py", ".md")]
    bundle = zip_bytes({p.name: p.read_bytes() for p in files})
    r = client.post("/v1/scenes", files={"bundle": ("textured.zip", bundle, "application/zip")})
    assert r.status_code == 201, r.text
    scene = r.json()
    r = client.post("/v1/jobs", json={"scene_id": scene["id"], "spp": 2, "width": 24, "height": 18})
    assert r.status_code == 202, r.text
    job = wait_job(client, r.json()["id"])
    assert job["status"] == "done", job
    npy = np.load(io.BytesIO(client.get(f"/v1/jobs/{job['id']}/result?format=npy").content))
    from tracer.scene import format as fmt

    state = load_scene(folder / "scene.json")
    camera = fmt.override(state.camera, width=24, height=18)
    expected = render_image(compile_scene(state), camera, fmt.override(state.render, spp=2))[0]
    assert np.array_equal(npy, expected)


def test_animation_by_keyframes_and_camera_path(client):
    scene = upload_json(client, animated_scene(frames=4))
    assert scene["animation"]["frames"] == 4
    r = client.post(
        "/v1/jobs", json={"scene_id": scene["id"], "kind": "animation", "spp": 1, "frames": [1, 3]}
    )
    job = wait_job(client, r.json()["id"])
    assert job["status"] == "done" and [f["frame"] for f in job["frames"]] == [1, 3]
    a = client.get(f"/v1/jobs/{job['id']}/frames/1?format=npy").content
    b = client.get(f"/v1/jobs/{job['id']}/frames/3?format=npy").content
    assert a != b
    # the scene itself never moved: its version is still 0
    assert client.get(f"/v1/scenes/{scene['id']}").json()["version"] == 0
    path = [
        {"position": [0, 1.5, 4], "look_at": [0, 0.5, 0]},
        {"position": [2, 1.5, 3], "look_at": [0, 0.5, 0]},
    ]
    r = client.post(
        "/v1/jobs",
        json={"scene_id": scene["id"], "kind": "animation", "spp": 1, "camera_path": path},
    )
    job = wait_job(client, r.json()["id"])
    assert job["status"] == "done" and len(job["frames"]) == 2


def test_progressive_jobs(client):
    scene = upload_tiny(client)
    r = client.post("/v1/jobs", json={"scene_id": scene["id"], "target_error": 0.2, "max_spp": 64})
    job = wait_job(client, r.json()["id"])
    assert job["status"] == "done", job
    frame = job["frames"][0]
    assert frame["error_estimate"] is not None
    assert frame["error_estimate"] <= 0.2 or frame["spp"] >= 63
    r = client.post("/v1/jobs", json={"scene_id": scene["id"], "time_budget": 0.5, "max_spp": 4096})
    job = wait_job(client, r.json()["id"])
    assert job["status"] == "done" and job["frames"][0]["spp"] >= 2


def test_progressive_jobs_spot_check(client, spot_check_calls):
    """From 512 pixels on, a progressive job's waves end with spot checks through the
    coordinator before their estimate."""
    scene = upload_tiny(client)
    body = {"scene_id": scene["id"], "target_error": 0.2, "width": 32, "height": 24}
    job = wait_job(client, client.post("/v1/jobs", json=body).json()["id"])
    assert job["status"] == "done", job
    assert job["frames"][0]["error_estimate"] <= 0.2
    assert spot_check_calls and set(spot_check_calls) == {1}


def test_events_progress_and_cancel(client):
    scene = upload_json(client, animated_scene(frames=40))
    body = {"scene_id": scene["id"], "kind": "animation", "spp": 16, "width": 64, "height": 48}
    job = client.post("/v1/jobs", json=body).json()
    events = []
    with client.stream("GET", f"/v1/jobs/{job['id']}/events") as stream:
        assert stream.headers["content-type"].startswith("text/event-stream")
        kind = None
        for line in stream.iter_lines():
            if line.startswith("event: "):
                kind = line[7:]
            elif line.startswith("data: "):
                events.append((kind, json.loads(line[6:])))
                if kind == "frame" and events[-1][1]["frame"] >= 1:
                    r = client.post(f"/v1/jobs/{job['id']}/cancel")
                    assert r.status_code == 200 and r.json()["status"] == "cancelled"
                if kind in ("done", "error", "cancelled"):
                    break
    kinds = [k for k, _ in events]
    assert kinds[0] == "status" and "progress" in kinds and "frame" in kinds
    assert kinds[-1] == "cancelled"
    progress = next(d for k, d in events if k == "progress")
    assert progress["frames_total"] == 40 and progress["lines_total"] == 48
    final = client.get(f"/v1/jobs/{job['id']}").json()
    assert final["status"] == "cancelled" and 2 <= len(final["frames"]) < 40
    time.sleep(0.5)  # nothing more is rendered or recorded for it
    assert len(client.get(f"/v1/jobs/{job['id']}").json()["frames"]) == len(final["frames"])
    assert client.post(f"/v1/jobs/{job['id']}/cancel").status_code == 409
    assert client.get(f"/v1/jobs/{job['id']}/frames/0?format=png").status_code == 200


def test_status_answers_while_rendering(client):
    """The event loop never waits for the cluster: status requests stay fast while a job
    renders (the strict p99 target is measured by bench/api_latency.py)."""
    scene = upload_tiny(client)
    body = {"scene_id": scene["id"], "spp": 256, "width": 160, "height": 120}
    job = client.post("/v1/jobs", json=body).json()
    times = []
    while True:
        start = time.perf_counter()
        status = client.get(f"/v1/jobs/{job['id']}").json()
        times.append(time.perf_counter() - start)
        if status["status"] != "queued" and status["status"] != "running":
            break
        time.sleep(0.01)
    assert status["status"] == "done"
    assert len(times) > 5 and sorted(times)[int(0.9 * len(times))] < 0.25, times


def test_queue_full_is_429(client, settings_of):
    scene = upload_tiny(client)
    settings_of(client, max_queue=1)
    body = {"scene_id": scene["id"], "spp": 64, "width": 64, "height": 64}
    first = client.post("/v1/jobs", json=body)
    assert first.status_code == 202
    r = client.post("/v1/jobs", json=body)
    assert r.status_code == 429 and r.json()["error"]["code"] == "queue_full"
    assert r.headers["retry-after"]
    wait_job(client, first.json()["id"])


def test_concurrent_submissions_cannot_pass_the_queue_limit(client, settings_of, monkeypatch):
    """Twelve submissions at once against room for three: exactly three are admitted (the
    count and the insert are one step), the others get 429 and leave no job directory."""
    from concurrent.futures import ThreadPoolExecutor

    scene = upload_tiny(client)
    ctx = client.app.state.ctx
    monkeypatch.setattr(ctx.service.jobs, "submit", lambda job_id: None)  # they stay queued
    active = len(ctx.store.unfinished_jobs())
    settings_of(client, max_queue=active + 3)
    body = {"scene_id": scene["id"], "spp": 1, "width": 16, "height": 16}
    jobs_before = set((client.app.state.settings.data_dir / "jobs").glob("*"))
    with ThreadPoolExecutor(12) as pool:
        answers = list(pool.map(lambda _: client.post("/v1/jobs", json=body), range(12)))
    codes = sorted(r.status_code for r in answers)
    assert codes == [202] * 3 + [429] * 9, codes
    admitted = {r.json()["id"] for r in answers if r.status_code == 202}
    made = {p.name for p in set((client.app.state.settings.data_dir / "jobs").glob("*"))}
    assert made - {p.name for p in jobs_before} == admitted
    for job_id in admitted:
        assert client.post(f"/v1/jobs/{job_id}/cancel").status_code == 200


def test_cluster_and_balancer(client):
    info = client.get("/v1/cluster").json()
    assert info["ready"] and len(info["tracers"]) == 1
    assert info["tracers"][0]["state"] == "ready"
    r = client.put("/v1/cluster/balancer", json={"name": "robin-hood"})
    assert r.status_code == 200 and r.json()["balancer"] == "robin-hood"
    client.put("/v1/cluster/balancer", json={"name": "cost-aware"})
    info = client.get("/v1/cluster").json()
    if info["last_frame"]:
        tracer = info["tracers"][0]
        assert tracer["lines_last_frame"] == info["last_frame"]["height"]
        assert tracer["idle_percent"] == 0.0


def test_a_tracer_killed_while_idle_shows_within_two_seconds(client):
    """SIGKILL of the idle tracer's process: /v1/cluster stops calling it ready (or shows the
    restarted process) within two seconds, with no render to notice it; it comes back."""
    tracer = client.get("/v1/cluster").json()["tracers"][0]
    assert tracer["state"] == "ready" and tracer["pid"] is not None
    os.kill(tracer["pid"], signal.SIGKILL)
    killed = time.monotonic()
    seen = tracer
    while seen["state"] == "ready" and seen["pid"] == tracer["pid"]:
        assert time.monotonic() - killed < 2.0, "the killed tracer still shows as ready"
        time.sleep(0.05)
        seen = client.get("/v1/cluster").json()["tracers"][0]
    assert seen["failures"] == tracer["failures"] + 1
    while seen["state"] != "ready":  # Ray restarts it; its probe brings it back
        assert time.monotonic() - killed < 120.0
        time.sleep(0.2)
        seen = client.get("/v1/cluster").json()["tracers"][0]


def test_tiny_scene_helper_is_valid():
    assert tiny_scene()["camera"]["width"] == 12

"""Interactive sessions through the test client: frames, camera updates, commits showing in
the frames, stats, closing and idle expiry. (The endless MJPEG stream is read from a real
server in test_live.py: the test client cannot end an infinite response.)"""

import gc
import io
import time
import weakref

import numpy as np
from PIL import Image

from tests.api.conftest import upload_tiny


def jpeg(response) -> np.ndarray:
    assert response.status_code == 200, response.text
    assert response.headers["content-type"] == "image/jpeg"
    return np.asarray(Image.open(io.BytesIO(response.content)).convert("RGB"), np.float64)


def next_frame(client, session_id: str, after: int):
    r = client.get(f"/v1/sessions/{session_id}/frame.jpg", params={"after": after})
    return jpeg(r), int(r.headers["x-frame-seq"]), int(r.headers["x-frame-version"])


def open_session(client, scene_id: str, **extra) -> dict:
    r = client.post("/v1/sessions", json={"scene_id": scene_id, "width": 48, "height": 32, **extra})
    assert r.status_code == 201, r.text
    return r.json()


def test_session_frames_commits_and_camera(client):
    scene = upload_tiny(client)
    session = open_session(client, scene["id"])
    sid = session["id"]
    assert session["stream_url"] == f"/v1/sessions/{sid}/stream"
    first, seq, version = next_frame(client, sid, 0)
    assert first.shape == (32, 48, 3) and first.mean() > 1.0 and version == 0

    # A commit shows in a later frame: the floor and cube turn red.
    ops = [{"op": "set_material", "name": "grey", "material": {"reflectance": [0.9, 0.0, 0.0]}}]
    assert (
        client.post(f"/v1/scenes/{scene['id']}/commits", json=ops and {"ops": ops}).status_code
        == 200
    )
    deadline = time.monotonic() + 60
    before = first.mean((0, 1))
    while True:  # the session blends the change in over a few frames
        image, seq, version = next_frame(client, sid, seq)
        means = image.mean((0, 1))
        turned_red = means[1] < 0.9 * before[1] and means[0] > means[1] + 5
        if (version == 1 and turned_red) or time.monotonic() > deadline:
            break
    # green light comes only from the white lamp now: the picture turned red
    assert version == 1 and turned_red, (means, before)

    # A camera update shows too, and its latency is reported.
    r = client.put(f"/v1/sessions/{sid}/camera", json={"position": [3, 4, 3], "look_at": [0, 0, 0]})
    assert r.status_code == 200, r.text
    moved, seq, _ = next_frame(client, sid, seq)
    moved, seq, _ = next_frame(client, sid, seq)
    assert np.abs(moved - image).mean() > 1.0
    stats = client.get(f"/v1/sessions/{sid}").json()["stats"]
    assert stats["camera_latency_ms"] is not None and stats["camera_latency_ms"] > 0
    assert stats["frames_streamed"] >= 3 and "fps" in stats and "spp" in stats

    listed = client.get("/v1/sessions").json()
    assert sid in [s["id"] for s in listed["data"]]
    assert client.delete(f"/v1/sessions/{sid}").status_code == 204
    assert client.get(f"/v1/sessions/{sid}").status_code == 404


def test_sessions_limit_and_expiry(client, settings_of):
    scene = upload_tiny(client)
    settings_of(client, max_sessions=1, session_idle_seconds=1.0)
    session = open_session(client, scene["id"])
    r = client.post("/v1/sessions", json={"scene_id": scene["id"]})
    assert r.status_code == 429 and r.json()["error"]["code"] == "too_many_sessions"
    deadline = time.monotonic() + 15
    while client.get(f"/v1/sessions/{session['id']}").status_code == 200:
        assert time.monotonic() < deadline, "the idle session did not expire"
        time.sleep(1.5)  # polling the status counts as activity: poll slower than the limit
    assert open_session(client, scene["id"])["id"] != session["id"]


def test_concurrent_opens_cannot_pass_the_session_limit(client, settings_of, monkeypatch):
    """Eight opens at once against room for two, each taking a while to set up: exactly two
    sessions open (counted on the render thread, the one writer of the sessions table), the
    others get 429."""
    from concurrent.futures import ThreadPoolExecutor

    service = client.app.state.ctx.service
    factory = service.session_factory()

    def slow_factory(*args, **kwargs):
        time.sleep(0.2)  # a cluster session that takes a while to start
        return factory(*args, **kwargs)

    monkeypatch.setattr(service, "session_factory", lambda: slow_factory)
    scene = upload_tiny(client)
    open_now = client.get("/v1/sessions").json()["count"]
    settings_of(client, max_sessions=open_now + 2)
    body = {"scene_id": scene["id"], "width": 48, "height": 32}
    with ThreadPoolExecutor(8) as pool:
        answers = list(pool.map(lambda _: client.post("/v1/sessions", json=body), range(8)))
    codes = sorted(r.status_code for r in answers)
    assert codes == [201] * 2 + [429] * 6, codes
    assert all(
        r.json()["error"]["code"] == "too_many_sessions" for r in answers if r.status_code == 429
    )
    for r in answers:
        if r.status_code == 201:
            assert client.delete(f"/v1/sessions/{r.json()['id']}").status_code == 204


def test_deleting_the_scene_closes_its_sessions(client):
    scene = upload_tiny(client)
    session = open_session(client, scene["id"])
    next_frame(client, session["id"], 0)
    assert client.delete(f"/v1/scenes/{scene['id']}").status_code == 204
    deadline = time.monotonic() + 10
    while client.get(f"/v1/sessions/{session['id']}").status_code == 200:
        assert time.monotonic() < deadline
        time.sleep(0.05)


def test_session_frames_show_in_the_cluster_stats(client):
    """/v1/cluster reports the session's frames: their size, each tracer's lines, the rays
    traced (also counted in /metrics)."""
    scene = upload_tiny(client)
    session = open_session(client, scene["id"])
    _, seq, _ = next_frame(client, session["id"], 0)
    next_frame(client, session["id"], seq)
    info = client.get("/v1/cluster").json()
    last = info["last_frame"]
    assert last["kind"] == "session"
    assert sum(t["lines"] for t in last["tracers"].values()) == last["height"] <= 32
    assert sum(t["lines_last_frame"] or 0 for t in info["tracers"]) == last["height"]
    assert last["rays"] >= last["width"] * last["height"] * last["spp"]  # a camera ray each
    assert last["calls"] >= 1 and last["pooled"] is False  # one tracer: no line pool
    metrics = client.get("/metrics").text
    counted = [line for line in metrics.splitlines() if line.startswith("tilerender_rays_total")]
    assert any('kind="session"' in line and float(line.split()[-1]) > 0 for line in counted)
    client.delete(f"/v1/sessions/{session['id']}")


def test_jobs_and_sessions_share_the_cluster(client):
    """A long job does not starve a session: frames keep coming while it renders."""
    scene = upload_tiny(client)
    body = {
        "scene_id": scene["id"],
        "kind": "animation",
        "spp": 32,
        "width": 96,
        "height": 64,
        "camera_path": [{"position": [0, 1.5, 4], "look_at": [0, 0.5, 0]}] * 8,
    }
    job = client.post("/v1/jobs", json=body).json()
    session = open_session(client, scene["id"])
    seq = 0
    seen = 0
    while client.get(f"/v1/jobs/{job['id']}").json()["status"] in ("queued", "running"):
        _, seq, _ = next_frame(client, session["id"], seq)
        seen += 1
    assert seen >= 3
    assert client.get(f"/v1/jobs/{job['id']}").json()["status"] == "done"
    client.delete(f"/v1/sessions/{session['id']}")


def test_a_session_over_the_pixel_limit_is_refused(client, settings_of):
    scene = upload_tiny(client)
    settings_of(client, max_session_pixels=48 * 32)
    r = client.post("/v1/sessions", json={"scene_id": scene["id"], "width": 64, "height": 32})
    assert r.status_code == 422, r.text
    error = r.json()["error"]
    assert error["code"] == "limit"
    assert "64x32 has 2048 pixels, more than the limit of 1536" in error["message"]
    assert open_session(client, scene["id"])["width"] == 48  # 48x32: at the limit
    assert client.get("/v1/sessions").json()["count"] >= 1


def test_closing_a_session_lets_go_of_its_image_buffers(client):
    """The session's blended image, the last frame shown, the coordinator's frame behind it
    and the latest JPEG are all released on close, even though the session objects may stay
    referenced (the render thread remembers the last worker it served)."""
    scene = upload_tiny(client)
    session = open_session(client, scene["id"])
    next_frame(client, session["id"], 0)
    service = client.app.state.ctx.service
    live = service.sessions[session["id"]]

    def close_and_watch(_coordinator):  # between two turns: no frame is being made
        s = live.session
        buffers = (s._image, s._last.image, s.last_frame.rgb)
        refs = [weakref.ref(b) for b in buffers]
        service._close_session(live, "closed")
        return refs

    refs = service.call(close_and_watch).result(timeout=60)
    gc.collect()
    assert [ref() is None for ref in refs] == [True, True, True]
    assert live.jpeg is None and live.session.closed


def test_a_session_denoises_its_stream_on_request(client, monkeypatch):
    """A session opened with ``denoise`` streams denoised frames and reports the denoiser's
    report with each; PATCH turns it off and on; a bad quality is a 422 and a missing denoiser
    a 503, both leaving the session as it was."""
    from tracer.post import denoise as denoise_module

    scene = upload_tiny(client)
    session = open_session(client, scene["id"], denoise="fast")
    sid = session["id"]
    assert session["denoise"] == "fast"
    seq, last = 0, None
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:  # the first frames may be published before the stats
        _, seq, _ = next_frame(client, sid, seq)
        last = client.get(f"/v1/sessions/{sid}").json()["stats"]
        if last["last_frame"].get("denoise"):
            break
    report = last["last_frame"]["denoise"]
    assert report["quality"] == "fast" and report["guides"] == ["albedo", "normal"]
    assert report["prefiltered"] is False and report["seconds"] > 0
    assert last["denoise"] == "fast" and last["denoise_ms"] > 0

    assert client.patch(f"/v1/sessions/{sid}", json={"denoise": "sharp"}).status_code == 422

    def unavailable():
        raise denoise_module.DenoiserUnavailable("no pyoidn here")

    with monkeypatch.context() as m:
        m.setattr("api.routes.sessions.require_denoiser", unavailable)
        r = client.patch(f"/v1/sessions/{sid}", json={"denoise": "high"})
        assert r.status_code == 503 and "no pyoidn here" in r.json()["error"]["message"], r.text
    assert client.get(f"/v1/sessions/{sid}").json()["denoise"] == "fast"

    r = client.patch(f"/v1/sessions/{sid}", json={"denoise": "off"})
    assert r.status_code == 200 and r.json()["denoise"] == "off"
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        _, seq, _ = next_frame(client, sid, seq)
        if client.get(f"/v1/sessions/{sid}").json()["stats"]["last_frame"]["denoise"] is None:
            break
    else:
        raise AssertionError("the stream still shows denoised frames")
    assert client.delete(f"/v1/sessions/{sid}").status_code == 204

"""Hostile and malformed requests (#22): bounded before work, off the event loop, refused
before the body is read when unauthenticated; and what the service says about itself (405
``Allow``, the OpenAPI document) matches what it does.

The tests that need no scene run on an app without its lifespan (routing, auth and body
parsing come before any route needs the cluster)."""

import asyncio
import json
import tempfile
import threading

import pytest
from fastapi.testclient import TestClient

from api.app import create_app
from tests.api.conftest import make_settings, upload_tiny

TOKEN = "s3cret-token"
POSE = {"position": [0, 1, 4], "look_at": [0, 0, 0]}


def plain_app(**changes):
    return create_app(make_settings(tempfile.mkdtemp(prefix="tilerender-A-"), **changes))


def json_error(response, status: int, word: str = "") -> dict:
    assert response.status_code == status, response.text
    assert response.headers["content-type"] == "application/json", response.headers
    error = response.json()["error"]
    assert error["status"] == status and error["message"], error
    assert word.lower() in error["message"].lower(), error["message"]
    return error


# --- Item 2: bounded, off the loop, auth first -------------------------------------------


def test_a_hostile_camera_path_is_refused_by_the_model(client):
    """Over the model's 10,000 poses: 422; 400,000 poses (24 MB) are over the 4 MiB a job's
    body may have: 413 before anything parses them (their parse held the GIL for a second)."""
    scene = upload_tiny(client)
    body = {"scene_id": scene["id"], "kind": "animation", "camera_path": [POSE] * 20_000}
    json_error(client.post("/v1/jobs", json=body), 422, "at most 10000")
    body["camera_path"] = [POSE] * 400_000
    json_error(client.post("/v1/jobs", json=body), 413, "larger than the limit")
    frames = {"scene_id": scene["id"], "kind": "animation", "frames": list(range(200_000))}
    json_error(client.post("/v1/jobs", json=frames), 422, "at most 100000")


def test_frames_over_the_setting_are_refused_before_any_camera_is_built(client, monkeypatch):
    """A camera path within the model's ceiling but over ``max_frames`` is counted, not
    built: the 422 comes without one camera made (it used to build all of them first), and
    the checks run in a worker thread, not on the event loop."""
    import api.routes.jobs as jobs

    built, threads = [], []
    real_frames, real_plan = jobs.job_frames, jobs._plan

    def counting_frames(state, request):
        built.append(len(request.get("camera_path") or ()))
        return real_frames(state, request)

    def watched_plan(*args):
        try:
            asyncio.get_running_loop()
            threads.append("event loop")
        except RuntimeError:
            threads.append("worker")
        return real_plan(*args)

    monkeypatch.setattr(jobs, "job_frames", counting_frames)
    monkeypatch.setattr(jobs, "_plan", watched_plan)
    scene = upload_tiny(client)
    body = {"scene_id": scene["id"], "kind": "animation", "camera_path": [POSE] * 5000}
    json_error(client.post("/v1/jobs", json=body), 422, "5000 frames: at most 1000")
    assert built == [] and threads == ["worker"]


def test_a_body_is_parsed_off_the_event_loop(client, monkeypatch):
    """While a request's JSON body is being parsed, /healthz answers: the parse is held until
    it has (on the event loop, the hold would keep /healthz waiting until it timed out)."""
    parsing, answered, held = threading.Event(), threading.Event(), []
    real_loads = json.loads

    def loads(data, *args, **kwargs):
        if isinstance(data, bytes) and b"hold-the-parse" in data:
            parsing.set()
            held.append(answered.wait(10))
        return real_loads(data, *args, **kwargs)

    monkeypatch.setattr(json, "loads", loads)
    result = {}

    def submit():
        result["job"] = client.post("/v1/jobs", json={"scene_id": "hold-the-parse"})

    thread = threading.Thread(target=submit)
    thread.start()
    assert parsing.wait(10)
    assert client.get("/healthz").status_code == 200
    answered.set()
    thread.join(30)
    assert held == [True]
    json_error(result["job"], 404, "no scene")


def test_hard_ceilings_of_lists_and_vectors(client):
    scene = upload_tiny(client)
    ops = {"ops": [{"op": "set_sky", "sky": {"radiance": [0, 0, 0]}}] * 10_001}
    json_error(client.post(f"/v1/scenes/{scene['id']}/commits", json=ops), 422, "at most 10000")
    ray = {"origin": [0.0] * 400_000, "direction": [0, 0, 1]}
    json_error(client.post(f"/v1/scenes/{scene['id']}/query", json=ray), 422, "3 components")
    camera = {"position": [0.0] * 400_000, "look_at": [0, 0, 0]}
    json_error(client.put("/v1/sessions/v000000000000/camera", json=camera), 422, "3 components")


def test_settings_cannot_exceed_the_models_ceilings(tmp_path):
    from pydantic import ValidationError

    with pytest.raises(ValidationError):
        make_settings(tmp_path, max_frames=10**6)
    with pytest.raises(ValidationError):
        make_settings(tmp_path, max_ops=10**6)


class CountingReceive:
    """An ASGI receive that serves ``body`` and counts how often it was called."""

    def __init__(self, body: bytes) -> None:
        self.body = body
        self.calls = 0

    async def __call__(self) -> dict:
        self.calls += 1
        return {"type": "http.request", "body": self.body, "more_body": False}


def asgi_post(app, path: str, body: bytes, headers: list, query: bytes = b"") -> tuple:
    """POST ``body`` straight to the ASGI app: (status, headers, body, receive calls)."""
    receive, sent = CountingReceive(body), []

    async def send(message):
        sent.append(message)

    scope = {
        "type": "http",
        "asgi": {"version": "3.0"},
        "http_version": "1.1",
        "method": "POST",
        "scheme": "http",
        "path": path,
        "raw_path": path.encode(),
        "root_path": "",
        "query_string": query,
        "headers": [(b"content-type", b"application/json"), *headers],
        "client": ("127.0.0.1", 1),
        "server": ("127.0.0.1", 80),
    }
    asyncio.run(app(scope, receive, send))
    start = next(m for m in sent if m["type"] == "http.response.start")
    content = b"".join(m.get("body", b"") for m in sent if m["type"] == "http.response.body")
    return start["status"], dict(start["headers"]), json.loads(content), receive.calls


def test_without_the_token_the_body_is_never_read():
    app = plain_app(token=TOKEN)
    body = json.dumps({"scene_id": "s1", "kind": "animation", "camera_path": [POSE] * 1000})
    status, headers, error, reads = asgi_post(app, "/v1/jobs", body.encode(), [])
    assert (status, reads) == (401, 0) and headers[b"www-authenticate"] == b"Bearer", error
    assert error["error"]["code"] == "unauthorized"
    wrong = [(b"authorization", b"Bearer wrong-token")]
    status, _, error, reads = asgi_post(app, "/v1/jobs", body.encode(), wrong)
    assert (status, reads) == (403, 0), error
    status, _, error, reads = asgi_post(app, "/v1/jobs", b"{}", [], query=b"access_token=nope")
    assert (status, reads) == (403, 0), error
    right = [(b"authorization", f"Bearer {TOKEN}".encode())]
    status, _, error, reads = asgi_post(app, "/v1/jobs", b"{}", right)
    assert status == 503 and reads >= 1, error  # past the gate: read (no lifespan here: 503)


# --- Item 10: what the service says about itself ------------------------------------------


@pytest.mark.parametrize(
    "method,path,allow",
    [
        ("PUT", "/v1/scenes", "GET, POST"),
        ("DELETE", "/v1/jobs", "GET, POST"),
        ("PUT", "/v1/scenes/s000000000000", "DELETE, GET, PATCH"),
        ("GET", "/v1/scenes/s000000000000/commits", "POST"),
        ("POST", "/v1/sessions/v000000000000", "DELETE, GET, PATCH"),
        ("PATCH", "/v1/sessions", "GET, POST"),
        ("GET", "/v1/cluster/balancer", "PUT"),
        ("POST", "/healthz", "GET"),
        ("POST", "/static/app.js", "GET, HEAD"),
    ],
)
def test_405_lists_every_method_of_the_path(method, path, allow):
    response = TestClient(plain_app()).request(method, path)
    error = json_error(response, 405, f"{method} is not allowed")
    assert response.headers["allow"] == allow, error


def test_openapi_declares_400_on_every_body_and_security_only_with_a_token():
    doc = TestClient(plain_app()).get("/openapi.json").json()
    with_body = [
        (path, method)
        for path, operations in doc["paths"].items()
        for method, operation in operations.items()
        if "requestBody" in operation
    ]
    assert len(with_body) >= 8
    for path, method in with_body:
        assert "400" in doc["paths"][path][method]["responses"], (method, path)
    assert "securitySchemes" not in doc.get("components", {})
    assert not any("security" in op for ops in doc["paths"].values() for op in ops.values())

    secured = TestClient(plain_app(token=TOKEN)).get("/openapi.json").json()
    assert set(secured["components"]["securitySchemes"]) == {"bearer", "access_token"}
    for path, operations in secured["paths"].items():
        for operation in operations.values():
            assert ("security" in operation) == path.startswith("/v1/"), path


def test_body_parser_errors_are_json(client):
    """Malformed bodies of every kind the parsers meet get the service's JSON error body."""
    jobs = "/v1/jobs"
    as_json = {"content-type": "application/json"}
    error = json_error(client.post(jobs, content=b"{", headers=as_json), 400, "not valid JSON")
    assert error["code"] == "bad_request"
    json_error(client.post(jobs, content=b"\xff\xfe{", headers=as_json), 400, "UTF-8")
    json_error(client.post(jobs, content=b"[" * 100_000, headers=as_json), 400, "nests")
    digits = b'{"scene_id": "s1", "spp": ' + b"9" * 5000 + b"}"
    json_error(client.post(jobs, content=digits, headers=as_json), 400, "not valid JSON")
    multipart = "multipart/form-data; boundary=b"
    bodies = [
        ("multipart/form-data", b"--b\r\n"),  # no boundary
        (multipart, b"--b\r\nfoo\r\n\r\nxx\r\n--b--\r\n"),  # a header without a colon
        (multipart, b"--b\r\nContent-Disposition: form-data\r\n\r\nx\r\n--b--\r\n"),  # no name
    ]
    for ctype, body in bodies:
        response = client.post("/v1/scenes", content=body, headers={"content-type": ctype})
        json_error(response, 400)


def test_a_refused_cors_preflight_is_json():
    app = plain_app(cors_origins="http://viewer.example")
    r = TestClient(app).options(
        "/v1/scenes",
        headers={"Origin": "http://evil.example", "Access-Control-Request-Method": "POST"},
    )
    json_error(r, 400, "origin")


@pytest.mark.parametrize(
    ("method", "path", "headers", "status"),
    [
        ("POST", "/v1/jobs", [(b"content-length", b"1000")], 408),  # the body stalls
        ("GET", "/v1/jobs/j1", [], 504),  # the app is slow
        ("POST", "/v1/scenes", [(b"content-length", b"10")], 200),  # an upload has longer
    ],
)
def test_a_request_out_of_time_is_the_clients_408_or_the_services_504(
    method, path, headers, status
):
    """A request whose body has not all arrived when its time is up is answered 408 (a stalled
    client used to get the 504 of a slow service); an upload's time is ``upload_timeout``."""
    import asyncio

    from api.middleware import Timeout
    from api.settings import Settings

    async def app(scope, receive, send):
        if method == "POST":
            while (await receive()).get("more_body"):
                pass
        await asyncio.sleep(0.3)  # the service's own work
        await send({"type": "http.response.start", "status": 200, "headers": []})
        await send({"type": "http.response.body", "body": b""})

    async def receive():
        if method == "POST" and path == "/v1/jobs":
            received.append(1)
            if len(received) > 1:
                await asyncio.sleep(10)  # the rest of the body never comes
            return {"type": "http.request", "body": b"{", "more_body": True}
        return {"type": "http.request", "body": b"x" * 10, "more_body": False}

    received: list = []
    sent: list = []

    async def send(message):
        sent.append(message)

    settings = Settings(request_timeout=0.1, upload_timeout=1.0)
    scope = {"type": "http", "method": method, "path": path, "headers": headers}
    asyncio.run(Timeout(app, settings)(scope, receive, send))
    assert sent[0]["status"] == status

"""A corpus of bad requests, each answered with the right 4xx and a JSON error whose message
a person can read (never a stack trace); plus auth, CORS and the body limit."""

import json

import pytest
from fastapi.testclient import TestClient

from tests.api.conftest import (
    animated_scene,
    app_client,
    make_settings,
    tiny_json,
    upload_tiny,
    wait_job,
    zip_bytes,
)
from tests.gltf_files import add_lights, add_node, light_node, write_gltf
from tests.helpers import tiny_scene

OBJ = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"
BIG_ZERO = b"\0" * (4 << 20)


def scene_with(**changes) -> bytes:
    return json.dumps({**tiny_scene(), **changes}).encode()


def scene_referencing(path: str) -> bytes:
    scene = tiny_scene()
    scene["objects"][1]["shape"] = path
    return json.dumps(scene).encode()


def gltf_with_uri(uri: str) -> bytes:
    return json.dumps(
        {
            "asset": {"version": "2.0"},
            "buffers": [{"uri": uri, "byteLength": 36}],
            "meshes": [],
        }
    ).encode()


def upload(**files):
    return ("POST", "/v1/scenes", {"files": files})


# (name, request, expected status, a word the message contains)
UPLOADS = [
    ("no content type", ("POST", "/v1/scenes", {"content": b"x"}), 415, "content type"),
    (
        "plain text",
        ("POST", "/v1/scenes", {"content": b"x", "headers": {"content-type": "text/plain"}}),
        415,
        "content type",
    ),
    (
        "empty json body",
        ("POST", "/v1/scenes", {"content": b"", "headers": {"content-type": "application/json"}}),
        422,
        "empty",
    ),
    (
        "multipart without a scene",
        ("POST", "/v1/scenes", {"data": {"name": "x"}, "files": {"files": ("a.obj", OBJ)}}),
        422,
        "exactly one",
    ),
    (
        "scene and mesh",
        upload(scene=("s.json", tiny_json()), mesh=("a.obj", OBJ)),
        422,
        "exactly one",
    ),
    (
        "unknown form field",
        ("POST", "/v1/scenes", {"files": {"scene": ("s.json", tiny_json()), "extra": ("x", b"1")}}),
        422,
        "unknown form field",
    ),
    ("scene not json", upload(scene=("s.json", b"{not json")), 422, "JSON"),
    (
        "scene with NaN",
        upload(scene=("s.json", tiny_json().replace(b"45.0", b"NaN"))),
        422,
        "non-finite",
    ),
    ("scene unknown key", upload(scene=("s.json", scene_with(colour=1))), 422, "unknown key"),
    (
        "scene missing mesh file",
        upload(scene=("s.json", scene_referencing("missing.obj"))),
        422,
        "no such file",
    ),
    (
        "scene reference leaves",
        upload(scene=("s.json", scene_referencing("../etc/passwd"))),
        422,
        "leave",
    ),
    (
        "scene absolute reference",
        upload(scene=("s.json", scene_referencing("/etc/passwd"))),
        422,
        "relative",
    ),
    ("file named ..", upload(scene=("s.json", tiny_json()), files=("../evil.obj", OBJ)), 422, ".."),
    (
        "file absolute name",
        upload(scene=("s.json", tiny_json()), files=("/tmp/evil.obj", OBJ)),
        422,
        "absolute",
    ),
    (
        "file backslash name",
        upload(scene=("s.json", tiny_json()), files=("..\\evil.obj", OBJ)),
        422,
        "backslash",
    ),
    ("mesh unknown type", upload(mesh=("notes.txt", b"hello")), 422, "unknown mesh type"),
    ("mesh garbage obj", upload(mesh=("bad.obj", b"v 1 2\nf 9 9 9\n")), 422, "bad.obj"),
    ("mesh empty file", upload(mesh=("empty.stl", b"")), 422, "empty.stl"),
    ("mesh glb garbage", upload(mesh=("x.glb", b"glTF\x02\x00\x00\x00garbage")), 422, "x.glb"),
    ("gltf buffer outside", upload(mesh=("m.gltf", gltf_with_uri("../../etc/passwd"))), 422, ".."),
    (
        "gltf buffer absolute",
        upload(mesh=("m.gltf", gltf_with_uri("/etc/passwd"))),
        422,
        "absolute",
    ),
    ("obj mtllib outside", upload(mesh=("m.obj", b"mtllib ../x.mtl\n" + OBJ)), 422, ".."),
    ("bundle not a zip", upload(bundle=("b.zip", b"PK not really")), 422, "zip"),
    (
        "bundle traversal",
        upload(bundle=("b.zip", zip_bytes({"../scene.json": tiny_json()}))),
        422,
        "..",
    ),
    (
        "bundle absolute entry",
        upload(bundle=("b.zip", zip_bytes({"/scene.json": tiny_json()}))),
        422,
        "absolute",
    ),
    (
        "bundle symlink",
        upload(
            bundle=("b.zip", zip_bytes({"scene.json": tiny_json()}, links={"m.obj": "/etc/passwd"}))
        ),
        422,
        "link",
    ),
    (
        "bundle zip bomb",
        upload(bundle=("b.zip", zip_bytes({"scene.json": tiny_json(), "pad.bin": BIG_ZERO}))),
        413,
        "zip bomb",
    ),
    (
        "bundle without scene",
        upload(bundle=("b.zip", zip_bytes({"a.txt": b"1", "b.txt": b"2"}))),
        422,
        "no scene.json",
    ),
    (
        "bundle two jsons",
        upload(bundle=("b.zip", zip_bytes({"a.json": b"{}", "b.json": b"{}"}))),
        422,
        "several",
    ),
    (
        "raw zip traversal",
        (
            "POST",
            "/v1/scenes",
            {
                "content": zip_bytes({"a/../../x.json": b"{}"}),
                "headers": {"content-type": "application/zip"},
            },
        ),
        422,
        "..",
    ),
]

OTHERS = [
    ("unknown scene", ("GET", "/v1/scenes/s000000000000", {}), 404, "no scene"),
    ("unknown scene id shape", ("GET", "/v1/scenes/..%2Fetc", {}), 404, ""),
    ("unknown path", ("GET", "/v1/nothing", {}), 404, ""),
    ("wrong method", ("PUT", "/v1/scenes", {"json": {}}), 405, ""),
    ("unknown job", ("GET", "/v1/jobs/j000000000000", {}), 404, "no job"),
    ("cancel unknown job", ("POST", "/v1/jobs/j000000000000/cancel", {}), 404, "no job"),
    (
        "job for unknown scene",
        ("POST", "/v1/jobs", {"json": {"scene_id": "s000000000000"}}),
        404,
        "no scene",
    ),
    (
        "job malformed json",
        ("POST", "/v1/jobs", {"content": b"{", "headers": {"content-type": "application/json"}}),
        400,
        "not valid JSON",
    ),
    (
        "job unknown field",
        ("POST", "/v1/jobs", {"json": {"scene_id": "s1", "colour": 1}}),
        422,
        "unknown field",
    ),
    ("job spp zero", ("POST", "/v1/jobs", {"json": {"scene_id": "s1", "spp": 0}}), 422, "spp"),
    (
        "job two modes",
        ("POST", "/v1/jobs", {"json": {"scene_id": "s1", "spp": 4, "target_error": 0.1}}),
        422,
        "at most one",
    ),
    (
        "job frames on a still",
        ("POST", "/v1/jobs", {"json": {"scene_id": "s1", "frames": [0]}}),
        422,
        "animation",
    ),
    (
        "job negative budget",
        ("POST", "/v1/jobs", {"json": {"scene_id": "s1", "time_budget": -1}}),
        422,
        "time_budget",
    ),
    (
        "session for unknown scene",
        ("POST", "/v1/sessions", {"json": {"scene_id": "s000000000000"}}),
        404,
        "no scene",
    ),
    ("unknown session", ("GET", "/v1/sessions/v000000000000", {}), 404, "no session"),
    (
        "camera for unknown session",
        (
            "PUT",
            "/v1/sessions/v000000000000/camera",
            {"json": {"position": [0, 0, 1], "look_at": [0, 0, 0]}},
        ),
        404,
        "no session",
    ),
    (
        "unknown balancer",
        ("PUT", "/v1/cluster/balancer", {"json": {"name": "fastest"}}),
        422,
        "unknown balancer",
    ),
    (
        "query without a ray",
        ("POST", "/v1/scenes/s000000000000/query", {"json": {}}),
        422,
        "either",
    ),
]


def check(response, status: int, word: str) -> None:
    assert response.status_code == status, response.text
    body = response.json()
    assert set(body) == {"error"}, body
    error = body["error"]
    assert error["status"] == status and error["message"] and error["code"]
    assert "Traceback" not in response.text and 'File "' not in response.text
    assert word.lower() in error["message"].lower(), error["message"]


@pytest.mark.parametrize(
    "name,request_,status,word", UPLOADS + OTHERS, ids=[c[0] for c in UPLOADS + OTHERS]
)
def test_bad_request(client, name, request_, status, word):
    method, path, kwargs = request_
    check(client.request(method, path, **kwargs), status, word)


def scene_requests(scene_id: str, animated_id: str) -> list:
    job = {"scene_id": scene_id}
    return [
        (
            "commit unknown op",
            "POST",
            f"/v1/scenes/{scene_id}/commits",
            {"ops": [{"op": "explode"}]},
            422,
            "unknown operation",
        ),
        ("commit no ops", "POST", f"/v1/scenes/{scene_id}/commits", {"ops": []}, 422, "ops"),
        (
            "commit unknown node",
            "POST",
            f"/v1/scenes/{scene_id}/commits",
            {"ops": [{"op": "remove_node", "node": "ghost"}]},
            422,
            "ghost",
        ),
        (
            "commit singular transform",
            "POST",
            f"/v1/scenes/{scene_id}/commits",
            {"ops": [{"op": "set_transform", "node": "cube", "transform": {"scale": 0}}]},
            422,
            "singular",
        ),
        (
            "commit bad camera",
            "POST",
            f"/v1/scenes/{scene_id}/commits",
            {
                "ops": [
                    {"op": "set_camera", "camera": {"position": [0, 0, 0], "look_at": [0, 0, 0]}}
                ]
            },
            422,
            "look_at",
        ),
        ("job spp over limit", "POST", "/v1/jobs", {**job, "spp": 10**6}, 422, "spp"),
        (
            "job resolution over limit",
            "POST",
            "/v1/jobs",
            {**job, "width": 20000, "height": 10},
            422,
            "width",
        ),
        (
            "job resolution over service limit",
            "POST",
            "/v1/jobs",
            {**job, "width": 8000, "height": 10},
            422,
            "resolution",
        ),
        (
            "job animation of a still",
            "POST",
            "/v1/jobs",
            {**job, "kind": "animation"},
            422,
            "no animation",
        ),
        (
            "job frames out of range",
            "POST",
            "/v1/jobs",
            {"scene_id": animated_id, "kind": "animation", "frames": [0, 99]},
            422,
            "frames",
        ),
        (
            "job too many frames",
            "POST",
            "/v1/jobs",
            {
                **job,
                "kind": "animation",
                "camera_path": [{"position": [0, 1, 4], "look_at": [0, 0, 0]}] * 1001,
            },
            422,
            "frames",
        ),
        (
            "job bad camera path",
            "POST",
            "/v1/jobs",
            {
                **job,
                "kind": "animation",
                "camera_path": [{"position": [0, 0, 0], "look_at": [0, 0, 0]}],
            },
            422,
            "look_at",
        ),
        (
            "query zero direction",
            "POST",
            f"/v1/scenes/{scene_id}/query",
            {"origin": [0, 0, 0], "direction": [0, 0, 0]},
            422,
            "zero",
        ),
        (
            "query ray and pixel",
            "POST",
            f"/v1/scenes/{scene_id}/query",
            {"origin": [0, 0, 0], "direction": [0, 0, 1], "x": 1, "y": 1},
            422,
            "either",
        ),
        (
            "query pixel outside",
            "POST",
            f"/v1/scenes/{scene_id}/query",
            {"x": 500, "y": 1},
            422,
            "outside",
        ),
        (
            "session bad camera",
            "POST",
            "/v1/sessions",
            {"scene_id": scene_id, "camera": {"position": [0, 0, 0], "look_at": [0, 0, 0]}},
            422,
            "look_at",
        ),
        (
            "session too large",
            "POST",
            "/v1/sessions",
            {"scene_id": scene_id, "width": 9000, "height": 100},
            422,
            "resolution",
        ),
    ]


def test_bad_requests_on_a_scene(client):
    scene = upload_tiny(client)
    animated = client.post(
        "/v1/scenes", files={"scene": ("a.json", json.dumps(animated_scene()).encode())}
    ).json()
    cases = scene_requests(scene["id"], animated["id"])
    for name, method, path, body, status, word in cases:
        response = client.request(method, path, json=body)
        try:
            check(response, status, word)
        except AssertionError as error:
            raise AssertionError(f"{name}: {error}") from None
    # Nothing was half-applied: the scene is still at version 0.
    assert client.get(f"/v1/scenes/{scene['id']}").json()["version"] == 0
    assert len(UPLOADS) + len(OTHERS) + len(cases) >= 30


def test_result_before_it_exists(client):
    scene = upload_tiny(client)
    job = client.post("/v1/jobs", json={"scene_id": scene["id"], "spp": 1}).json()
    check(client.get(f"/v1/jobs/{job['id']}/frames/7"), 404, "no finished frame")
    check(client.get(f"/v1/jobs/{job['id']}/result?format=tiff"), 422, "format")
    wait_job(client, job["id"])


def test_limits_on_upload_size_and_triangles(client, settings_of):
    settings_of(client, max_upload_bytes=4096)
    big = tiny_json() + b" " * 5000
    check(client.post("/v1/scenes", files={"scene": ("s.json", big)}), 413, "limit")
    settings_of(client, max_upload_bytes=64 << 20, max_triangles=10)
    check(client.post("/v1/scenes", files={"scene": ("s.json", tiny_json())}), 422, "triangles")


def test_progressive_job_under_a_cap_below_one_wave(client, settings_of):
    scene = upload_tiny(client)
    settings_of(client, max_spp=2)
    body = {"scene_id": scene["id"], "target_error": 0.1}
    check(client.post("/v1/jobs", json=body), 422, "one wave of 4")
    body = {"scene_id": scene["id"], "max_spp": 3, "time_budget": 1.0}
    check(client.post("/v1/jobs", json=body), 422, "max_spp")


def test_bundle_limits(client, settings_of):
    settings_of(client, max_bundle_files=3)
    many = zip_bytes({f"f{i}.txt": b"x" for i in range(5)} | {"scene.json": tiny_json()})
    check(client.post("/v1/scenes", files={"bundle": ("b.zip", many)}), 413, "entries")
    settings_of(client, max_bundle_files=256, max_unpacked_bytes=2048)
    big = zip_bytes({"scene.json": tiny_json(), "pad.txt": b"abc" * 2000})
    check(client.post("/v1/scenes", files={"bundle": ("b.zip", big)}), 413, "unpacks")


def test_bearer_token(client, settings_of):
    settings_of(client, token="s3cret-token")
    check(client.get("/v1/scenes"), 401, "token")
    assert client.get("/v1/scenes").headers["www-authenticate"] == "Bearer"
    check(client.get("/v1/scenes", headers={"Authorization": "Basic abc"}), 401, "Bearer")
    check(
        client.get("/v1/scenes", headers={"Authorization": "Bearer wrong-token"}), 403, "not valid"
    )
    assert (
        client.get("/v1/scenes", headers={"Authorization": "Bearer s3cret-token"}).status_code
        == 200
    )
    assert client.get("/v1/scenes?access_token=s3cret-token").status_code == 200
    assert client.get("/healthz").status_code == 200  # health stays open
    assert client.get("/").status_code == 200


def test_cors(tmp_path):
    from api.app import create_app

    app = create_app(make_settings(tmp_path, cors_origins="http://viewer.example"))
    plain = TestClient(app)  # no lifespan: CORS answers before any route runs
    r = plain.options(
        "/v1/scenes",
        headers={"Origin": "http://viewer.example", "Access-Control-Request-Method": "POST"},
    )
    assert r.status_code == 200
    assert r.headers["access-control-allow-origin"] == "http://viewer.example"
    r = plain.options(
        "/v1/scenes",
        headers={"Origin": "http://evil.example", "Access-Control-Request-Method": "POST"},
    )
    assert "access-control-allow-origin" not in r.headers


def test_settings_refuse_unsafe_values(tmp_path):
    from pydantic import ValidationError

    with pytest.raises(ValidationError):
        make_settings(tmp_path, balancer="fastest")
    with pytest.raises(ValidationError):
        make_settings(tmp_path, token="short")
    with pytest.raises(ValidationError):
        make_settings(tmp_path, max_queue=0)


def test_an_upload_the_renderer_refuses_leaves_no_scene(client):
    """A scene that loads but that compiling refuses (a cube 1e38 away: float32 cannot hold it)
    is answered 422 and is not kept: the scene list is as before and no scene directory stays."""
    before = {s["id"] for s in client.get("/v1/scenes").json()["data"]}
    root = client.app.state.settings.data_dir / "scenes"
    dirs_before = {p.name for p in root.glob("*")}
    scene = tiny_scene()
    scene["objects"][1]["transform"]["translate"] = [1e38, 0.5, 0]
    r = client.post("/v1/scenes", files={"scene": ("scene.json", json.dumps(scene).encode())})
    assert r.status_code == 422, r.text
    assert {s["id"] for s in client.get("/v1/scenes").json()["data"]} == before
    assert {p.name for p in root.glob("*")} == dirs_before


def test_an_upload_that_times_out_leaves_no_scene(ray_session, tmp_path, monkeypatch):
    """An upload that outlasts the upload timeout after its scene was kept (here while its
    summary is described) is answered 504 and keeps nothing (it used to stay listed)."""
    import time

    from api.scenes import SceneRepository

    describe = SceneRepository.summary

    def slow_summary(self, entry):
        time.sleep(1.0)  # longer than the client may wait
        return describe(self, entry)

    monkeypatch.setattr(SceneRepository, "summary", slow_summary)
    with app_client(tmp_path / "data", upload_timeout=0.5) as client:
        r = client.post("/v1/scenes", files={"scene": ("scene.json", tiny_json())})
        assert r.status_code == 504, r.text
        time.sleep(1.5)  # past the worker thread's end, whatever it did
        assert client.get("/v1/scenes").json()["count"] == 0
        assert not any((tmp_path / "data" / "scenes").glob("*"))
        assert not any((tmp_path / "data" / "tmp").glob("u*"))


def test_a_commit_the_renderer_refuses_changes_nothing(client):
    """Commits are checked as strictly as uploads: one that flattens every triangle of the scene
    (update_vertices) or moves the cube 1e38 away (set_transform) is answered 422 and leaves the
    scene exactly as it was (both used to answer 200, then GET 422 and jobs failed); a job on the
    scene afterwards renders."""
    scene = upload_tiny(client)
    path = f"/v1/scenes/{scene['id']}"
    before = client.get(path).json()
    entry = client.app.state.ctx.scenes.get(scene["id"])
    state = entry.graph.state
    flatten = [
        {"op": "update_vertices", "mesh": name, "vertices": [[0.0, 0.0, 0.0]] * len(mesh.vertices)}
        for name, mesh in state.meshes.items()
    ]
    far = [{"op": "set_transform", "node": "cube", "transform": {"translate": [1e38, 0.5, 0]}}]
    for ops, word in ((flatten, "zero area"), (far, "float32")):
        check(client.post(f"{path}/commits", json={"ops": ops}), 422, word)
        assert entry.graph.state is state
        assert client.get(path).json() == before
    assert not any((entry.directory / "commits").iterdir())
    job = client.post("/v1/jobs", json={"scene_id": scene["id"], "spp": 1}).json()
    assert wait_job(client, job["id"])["status"] == "done"


def test_a_commit_compiles_from_the_previous_version(client, monkeypatch):
    """The check of a commit compiles its state from the kept compiled form of the version
    before (as the replicas do), not from scratch, and describes it as a fresh compile would."""
    import tracer.compiled.scene as compiled_scene
    from api.scenes import summary

    previous_given = []
    compile_scene = compiled_scene.compile_scene

    def watched(state, previous=None, *args, **kwargs):
        previous_given.append(previous is not None)
        return compile_scene(state, previous, *args, **kwargs)

    monkeypatch.setattr(compiled_scene, "compile_scene", watched)
    scene = upload_tiny(client)
    path = f"/v1/scenes/{scene['id']}"
    for k in range(3):
        move = {
            "op": "set_transform",
            "node": "cube",
            "transform": {"translate": [0.1 * k, 0.5, 0]},
        }
        assert client.post(f"{path}/commits", json={"ops": [move]}).status_code == 200
    assert previous_given == [False, True, True, True]
    entry = client.app.state.ctx.scenes.get(scene["id"])
    shown = client.get(path).json()
    assert shown["effects"] == summary(entry.graph.state)["effects"]


def test_a_query_never_answers_with_a_raw_ray_error(client, monkeypatch):
    """A tracer that fails a ray query is answered cleanly: its own reason for a scene it
    refuses (422), else 503; never Ray's text naming the actor, its pid and node IP (a refusal
    used to come back as 422 "ray::...query() (pid=..., ip=...)")."""
    from ray.exceptions import RayTaskError

    from tracer.errors import SceneError

    scene = upload_tiny(client)
    service = client.app.state.ctx.service
    for cause, status, word in (
        (SceneError("mesh 'cube': every triangle has zero area"), 422, "zero area"),
        (RuntimeError("numba crashed"), 503, "tracer failed"),
    ):
        error = RayTaskError(
            "TracerActor.query", "Traceback ...", cause, "ray::TracerActor.query", 4242, "10.9.8.7"
        ).as_instanceof_cause()

        def failing(_coordinator, error=error):
            raise error

        monkeypatch.setattr(service, "query_call", lambda *_args, failing=failing: failing)
        r = client.post(f"/v1/scenes/{scene['id']}/query", json={"x": 6, "y": 4})
        check(r, status, word)
        assert not any(s in r.text for s in ("4242", "10.9.8.7", "ray::", "pid=")), r.text


def test_upload_errors_name_no_server_path(client):
    """Upload errors name only what the client sent: a scene that is not JSON is named by its
    path in the upload (it was named by its server path, under the data directory), and a
    bundle entry that a file is in the way of is a 422 (it was a 500)."""
    data_dir = client.app.state.settings.data_dir
    clash = zip_bytes({"scene.json": tiny_json(), "a": b"x", "a/b.txt": b"y"})
    cases = (
        ({"scene": ("s.json", b"{not json")}, "scene.json: not valid JSON"),
        ({"bundle": ("b.zip", clash)}, "'a/b.txt': a file of the bundle is in its way"),
    )
    for files, words in cases:
        r = client.post("/v1/scenes", files=files)
        check(r, 422, words)
        assert str(data_dir) not in r.text and str(data_dir.resolve()) not in r.text, r.text


@pytest.mark.parametrize(
    "edit,words",
    [
        (lambda tree: tree.update(cameras=[]) or add_node(tree, {"camera": 0}), "camera 0"),
        (lambda tree: add_lights(tree, [{"type": "area"}]) or add_node(tree, light_node(0)),
         "unknown type 'area'"),
    ],
)  # fmt: skip
def test_a_gltf_with_a_bad_camera_or_light_is_refused(client, tmp_path, edit, words):
    """A glTF upload whose camera or light is malformed is answered 422 with the loader's
    message, not a 500."""
    gltf = write_gltf(tmp_path / "bad.gltf", edit).read_bytes()
    check(client.post("/v1/scenes", files={"mesh": ("bad.gltf", gltf)}), 422, words)

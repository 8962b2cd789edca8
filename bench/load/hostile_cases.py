"""The hostile corpus: requests a careless or malicious client sends, each with the answer the
service must give (issue #22: a specific 4xx with a JSON error, or a 2xx for an input that is
tricky but valid). ``bench/load/hostile.py`` runs them against a real ``tilerender serve``.

A case's ``send`` gets a :class:`Target` (the server, its fixture scenes and jobs) and returns
an :class:`Answer`; most are one request built by :func:`call` (paths and JSON bodies may name
fixtures: ``{scene}`` in a path, ``Ref("scene")`` in a body), a few write raw bytes to a socket
(:func:`raw`: bodies shorter than their Content-Length, headers alone) or are short sequences
(open a session, send it a bad camera, close it). Uploads are in ``hostile_uploads.py``.

Fixtures (made through the API before the cases run): ``scene`` (a small static scene),
``scratch`` (the same, for commits: made again when a case changed it), ``animated`` (4
keyframes), ``meshy`` (a deformable two-triangle mesh ``quad`` on node
``quad``) and ``done_job`` (a finished still of ``scene``).
"""

import json
import socket
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import httpx

MiB = 1 << 20
POSE = {"position": [0.0, 1.5, 4.0], "look_at": [0.0, 0.5, 0.0]}


@dataclass
class Answer:
    """What came back: ``status`` None when nothing did (timeout or closed connection)."""

    status: int | None
    headers: dict[str, str] = field(default_factory=dict)
    text: str = ""
    seconds: float = 0.0
    note: str = ""

    def json(self) -> Any:
        return json.loads(self.text)


@dataclass
class Target:
    """A server under test: its URL, an HTTP client on it, the fixtures' ids and the token
    the client sends (None: no Authorization header)."""

    url: str
    client: httpx.Client
    fixtures: dict[str, str] = field(default_factory=dict)
    token: str | None = None

    def request(self, method: str, path: str, timeout: float = 30.0, **kwargs) -> Answer:
        headers = dict(kwargs.pop("headers", None) or {})
        if self.token is not None:
            headers.setdefault("Authorization", f"Bearer {self.token}")
        start = time.perf_counter()
        try:
            r = self.client.request(method, path, headers=headers, timeout=timeout, **kwargs)
        except httpx.TimeoutException:
            return Answer(None, seconds=time.perf_counter() - start, note="timed out")
        except httpx.TransportError as exc:
            return Answer(None, seconds=time.perf_counter() - start, note=type(exc).__name__)
        return Answer(r.status_code, dict(r.headers), r.text, time.perf_counter() - start)

    def raw(self, data: bytes, timeout: float = 5.0, shut_write: bool = False) -> Answer:
        """Write ``data`` to a fresh connection (half-closing it if ``shut_write``), read the
        answer until the server closes or ``timeout`` passes."""
        host, port = self.url.removeprefix("http://").split(":")
        start = time.perf_counter()
        received = b""
        with socket.create_connection((host, int(port)), timeout=timeout) as sock:
            try:
                sock.sendall(data)
                if shut_write:
                    sock.shutdown(socket.SHUT_WR)
                while chunk := sock.recv(65536):
                    received += chunk
                    if _complete(received):
                        break
            except TimeoutError:
                pass
            except OSError as exc:  # reset by the peer while we were still sending
                if not received:
                    return Answer(None, seconds=time.perf_counter() - start, note=str(exc))
        seconds = time.perf_counter() - start
        if not received:
            return Answer(None, seconds=seconds, note="no answer")
        return _parse(received, seconds)


def _complete(data: bytes) -> bool:
    head, sep, body = data.partition(b"\r\n\r\n")
    if not sep:
        return False
    for line in head.split(b"\r\n")[1:]:
        name, _, value = line.partition(b":")
        if name.strip().lower() == b"content-length":
            return len(body) >= int(value)
    return False


def _parse(data: bytes, seconds: float) -> Answer:
    head, _, body = data.partition(b"\r\n\r\n")
    lines = head.decode("latin-1").split("\r\n")
    status = int(lines[0].split()[1])
    headers = {}
    for line in lines[1:]:
        name, _, value = line.partition(":")
        headers[name.strip().lower()] = value.strip()
    return Answer(status, headers, body.decode("utf-8", "replace"), seconds)


@dataclass(frozen=True)
class Ref:
    """A fixture's id inside a request body."""

    name: str


def _resolve(value, fixtures: dict[str, str]):
    if isinstance(value, Ref):
        return fixtures[value.name]
    if isinstance(value, dict):
        return {k: _resolve(v, fixtures) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_resolve(v, fixtures) for v in value]
    return value


Send = Callable[[Target], Answer]


@dataclass(frozen=True)
class Case:
    """One hostile input and the answer it must get (``expect`` None: none, the client broke
    off).

    ``word``: a word the error message contains; ``allow``: the methods a 405's Allow header
    lists; ``keeps``: a fixture scene whose version the case must not change (all or
    nothing); ``heavy``: ``/healthz`` is timed while it runs and must stay responsive;
    ``quick``: part of ``--quick``; ``auth``: runs against the server with a token;
    ``json_error``: a 4xx must carry the service's JSON error body."""

    name: str
    route: str
    expect: int | None
    send: Send
    word: str = ""
    allow: frozenset[str] | None = None
    keeps: str | None = None
    heavy: bool = False
    quick: bool = True
    auth: bool = False
    json_error: bool = True


def call(method: str, path: str, timeout: float = 30.0, **kwargs) -> Send:
    """One request; ``{fixture}`` in the path and ``Ref`` values in ``json`` are filled in."""

    def send(target: Target) -> Answer:
        body = {k: _resolve(v, target.fixtures) if k == "json" else v for k, v in kwargs.items()}
        return target.request(method, path.format(**target.fixtures), timeout, **body)

    return send


def raw(head: str, body: bytes = b"", timeout: float = 5.0, shut_write: bool = False) -> Send:
    """Raw bytes: ``head`` (request line and headers, ``{host}`` and fixtures filled in, and
    the target's token)."""

    def send(target: Target) -> Answer:
        host = target.url.removeprefix("http://")
        text = head.format(host=host, **target.fixtures)
        if target.token is not None:  # as Target.request: the client's token, if it has one
            text += f"\nAuthorization: Bearer {target.token}"
        text = text.replace("\n", "\r\n") + "\r\n\r\n"
        return target.raw(text.encode() + body, timeout, shut_write)

    return send


def json_bytes(text: str) -> Send:
    """POST /v1/jobs with ``text`` as its JSON body, exactly as written (``$scene``: the
    fixture scene's id)."""

    def send(target: Target) -> Answer:
        body = text.replace("$scene", target.fixtures.get("scene", MISSING)).encode()
        return target.request("POST", "/v1/jobs", content=body, headers=JSON)

    return send


JSON = {"content-type": "application/json"}


def job(**fields) -> Send:
    return call("POST", "/v1/jobs", json={"scene_id": Ref("scene"), **fields})


def animation(**fields) -> Send:
    return job(kind="animation", **fields)


def commit(*ops: dict, scene: str = "scratch") -> Send:
    return call("POST", f"/v1/scenes/{{{scene}}}/commits", json={"ops": list(ops)})


def query(**body) -> Send:
    return call("POST", "/v1/scenes/{scene}/query", json=body)


def session(**fields) -> Send:
    return call("POST", "/v1/sessions", json={"scene_id": Ref("scene"), "width": 16, **fields})


def on_session(method: str, suffix: str, **kwargs) -> Send:
    """Open a 16x16 session on ``scene``, send one request to it, close it; the answer is the
    middle request's."""

    def send(target: Target) -> Answer:
        opened = target.request("POST", "/v1/sessions", json=_resolve(SESSION, target.fixtures))
        if opened.status != 201:
            return Answer(None, note=f"could not open the session: {opened.status}")
        session_id = opened.json()["id"]
        try:
            return target.request(method, f"/v1/sessions/{session_id}{suffix}", **kwargs)
        finally:
            target.request("DELETE", f"/v1/sessions/{session_id}")

    return send


SESSION = {"scene_id": Ref("scene"), "width": 16, "height": 16}


def many_poses(count: int) -> Send:
    """An animation of ``count`` camera poses, the body written directly (json.dumps of 400k
    dicts would be the client's cost, not the server's)."""
    pose = json.dumps(POSE)
    body = '{"scene_id": "%s", "kind": "animation", "camera_path": [%s]}'

    def send(target: Target) -> Answer:
        text = body % (target.fixtures.get("scene", "s000000000000"), ",".join([pose] * count))
        return target.request("POST", "/v1/jobs", 60.0, content=text.encode(), headers=JSON)

    return send


def deep(levels: int) -> str:
    return "[" * levels + "]" * levels


QUAD = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]]
FLAT = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0], [3.0, 0.0, 0.0]]
"""The quad's four vertices on one line: both triangles zero-area."""
FAR = [[1e38, 0.0, 0.0], [1e38 + 1e32, 0.0, 0.0], [1e38, 1e32, 0.0], [1e38, 0.0, 1e32]]
MISSING = "s000000000000"


def methods(*names: str) -> frozenset[str]:
    return frozenset(names)


C = Case
COMMITS = "POST /v1/scenes/{id}/commits"
JOBS = "POST /v1/jobs"
QUERY = "POST /v1/scenes/{id}/query"
SESSIONS = "/v1/sessions"

COMMIT_CASES = [
    C("commit: unknown op", COMMITS, 422, commit({"op": "explode"}), keeps="scratch"),
    C("commit: no ops", COMMITS, 422, commit(), "ops", keeps="scratch"),
    C("commit: ops not a list", COMMITS, 422, call("POST", "/v1/scenes/{scratch}/commits",
      json={"ops": {"op": "set_sky"}}), keeps="scratch"),
    C("commit: unknown field", COMMITS, 422, call("POST", "/v1/scenes/{scratch}/commits",
      json={"ops": [], "force": True}), keeps="scratch"),
    C("commit: unknown node", COMMITS, 422, commit({"op": "remove_node", "node": "ghost"}),
      "ghost", keeps="scratch"),
    C("commit: node id -1", COMMITS, 422, commit({"op": "remove_node", "node": -1}),
      keeps="scratch"),
    C("commit: singular transform", COMMITS, 422, commit({"op": "set_transform", "node": "cube",
      "transform": {"scale": 0}}), "singular", keeps="scratch"),
    C("commit: translate 1e38", COMMITS, 422, commit({"op": "set_transform", "node": "cube",
      "transform": {"translate": [1e38, 0, 0]}}), keeps="scratch"),
    C("commit: translate NaN", COMMITS, 422, call("POST", "/v1/scenes/{scratch}/commits",
      content=b'{"ops": [{"op": "set_transform", "node": "cube", "transform": '
      b'{"translate": [NaN, 0, 0]}}]}', headers=JSON), keeps="scratch"),
    C("commit: update_vertices all zero-area", COMMITS, 422, commit({"op": "update_vertices",
      "mesh": "quad", "vertices": FLAT}, scene="meshy"), keeps="meshy"),
    C("commit: update_vertices 1e38 away", COMMITS, 422, commit({"op": "update_vertices",
      "mesh": "quad", "vertices": FAR}, scene="meshy"), keeps="meshy"),
    C("commit: update_vertices wrong count", COMMITS, 422, commit({"op": "update_vertices",
      "mesh": "quad", "vertices": QUAD[:3]}, scene="meshy"), "vertices", keeps="meshy"),
    C("commit: update_vertices Infinity", COMMITS, 422, call("POST",
      "/v1/scenes/{meshy}/commits", content=b'{"ops": [{"op": "update_vertices", "mesh": "quad",'
      b' "vertices": [[Infinity,0,0],[1,0,0],[1,1,0],[0,1,0]]}]}', headers=JSON), keeps="meshy"),
    C("commit: add_mesh faces out of range", COMMITS, 422, commit({"op": "add_mesh", "mesh": "m",
      "vertices": QUAD, "faces": [[0, 1, 9]]}), keeps="scratch"),
    C("commit: add_mesh of zero-area triangles", COMMITS, 422, commit(
      {"op": "add_mesh", "mesh": "flat", "vertices": FLAT, "faces": [[0, 1, 2], [0, 2, 3]]},
      {"op": "add_node", "name": "flat", "kind": "static", "mesh": "flat", "material": "grey"}),
      keeps="scratch"),
    C("commit: add_mesh empty", COMMITS, 422, commit({"op": "add_mesh", "mesh": "e",
      "vertices": [], "faces": []}), keeps="scratch"),
    C("commit: add_node of an unknown mesh", COMMITS, 422, commit({"op": "add_node", "name": "n",
      "kind": "static", "mesh": "nowhere", "material": "grey"}), keeps="scratch"),
    C("commit: add_node with an unknown parent", COMMITS, 422, commit({"op": "add_node",
      "name": "n", "kind": "static", "parent": "ghost"}), keeps="scratch"),
    C("commit: add_node with a 100k-character name", COMMITS, 422, commit({"op": "add_node",
      "name": "n" * 100_000, "kind": "static"}), keeps="scratch"),
    C("commit: assign an unknown material", COMMITS, 422, commit({"op": "assign_material",
      "node": "cube", "material": "gold"}), keeps="scratch"),
    C("commit: set_light on an unknown material", COMMITS, 422, commit({"op": "set_light",
      "material": "sun", "emission": [1, 1, 1]}), keeps="scratch"),
    C("commit: camera looking at itself", COMMITS, 422, commit({"op": "set_camera", "camera":
      {"position": [0, 0, 0], "look_at": [0, 0, 0]}}), "look_at", keeps="scratch"),
    C("commit: camera 1e38 away (valid: renders black)", COMMITS, 200, commit({"op": "set_camera",
      "camera": {"position": [1e38, 0, 0], "look_at": [0, 0, 0]}}, scene="meshy")),
    C("commit: render spp 0", COMMITS, 422, commit({"op": "set_render", "render": {"spp": 0}}),
      keeps="scratch"),
    C("commit: sky radiance and sky", COMMITS, 422, commit({"op": "set_sky", "radiance": [0, 0, 0],
      "sky": {"type": "constant", "radiance": [0, 0, 0]}}), keeps="scratch"),
    C("commit: bad kind", COMMITS, 422, commit({"op": "set_kind", "node": "cube",
      "kind": "liquid"}), keeps="scratch"),
    C("commit: valid op then a bad one", COMMITS, 422, commit(
      {"op": "set_sky", "radiance": [0.5, 0.5, 0.5]}, {"op": "remove_node", "node": "ghost"}),
      keeps="scratch"),
    C("commit: 1001 ops (over MAX_OPS)", COMMITS, 422, commit(
      *[{"op": "set_sky", "radiance": [0, 0, 0]}] * 1001), keeps="scratch"),
    C("commit: 300k ops", COMMITS, 422, commit(*[{"op": "set_sky", "radiance": [0, 0, 0]}]
      * 300_000), keeps="scratch", heavy=True, quick=False),
    C("commit: unknown scene", COMMITS, 404, call("POST", f"/v1/scenes/{MISSING}/commits",
      json={"ops": [{"op": "set_sky", "radiance": [0, 0, 0]}]}), "no scene"),
    C("commit: PATCH with a bad op", "PATCH /v1/scenes/{id}", 422, call("PATCH",
      "/v1/scenes/{scratch}", json={"ops": [{"op": "remove_node", "node": 10**30}]}),
      keeps="scratch"),
    C("commit: valid sky of 0 (tricky, valid)", COMMITS, 200, commit({"op": "set_sky",
      "radiance": [0, 0, 0]}, scene="meshy")),
]  # fmt: skip

JOB_CASES = [
    C("job: unknown scene", JOBS, 404, call("POST", "/v1/jobs", json={"scene_id": MISSING}),
      "no scene"),
    C("job: empty scene id", JOBS, 422, call("POST", "/v1/jobs", json={"scene_id": ""})),
    C("job: 10k-character scene id", JOBS, 422, call("POST", "/v1/jobs",
      json={"scene_id": "s" * 10_000})),
    C("job: unknown field", JOBS, 422, job(colour=1), "unknown field"),
    C("job: spp 0", JOBS, 422, job(spp=0), "spp"),
    C("job: spp -1", JOBS, 422, job(spp=-1), "spp"),
    C("job: spp 1.5", JOBS, 422, job(spp=1.5), "spp"),
    C("job: spp over MAX_SPP", JOBS, 422, job(spp=10**6), "spp"),
    C("job: spp of 40 digits", JOBS, 422, job(spp=10**40), "spp"),
    C("job: spp of 5000 digits", JOBS, 400, json_bytes(
      '{"scene_id": "x", "spp": 1' + "0" * 5000 + "}")),
    C("job: width 0", JOBS, 422, job(width=0), "width"),
    C("job: width over the service limit", JOBS, 422, job(width=8000, height=10), "resolution"),
    C("job: width 2**40", JOBS, 422, job(width=2**40, height=10)),
    C("job: height -5", JOBS, 422, job(height=-5), "height"),
    C("job: seed -1", JOBS, 422, job(seed=-1), "seed"),
    C("job: seed 2**64", JOBS, 422, job(seed=2**64), "seed"),
    C("job: max_depth 0", JOBS, 422, job(max_depth=0), "max_depth"),
    C("job: target_error 0", JOBS, 422, job(target_error=0), "target_error"),
    C("job: target_error NaN", JOBS, 422, json_bytes('{"scene_id": "x", "target_error": NaN}')),
    C("job: time_budget -1", JOBS, 422, job(time_budget=-1), "time_budget"),
    C("job: time_budget over MAX_TIME_BUDGET", JOBS, 422, job(time_budget=1e9), "time_budget"),
    C("job: time_budget Infinity", JOBS, 422, json_bytes(
      '{"scene_id": "$scene", "time_budget": Infinity}')),
    C("job: two modes", JOBS, 422, job(spp=4, target_error=0.1), "at most one"),
    C("job: kind video", JOBS, 422, job(kind="video"), "kind"),
    C("job: frames on a still", JOBS, 422, job(frames=[0]), "animation"),
    C("job: camera on an animation", JOBS, 422, animation(camera=POSE), "camera"),
    C("job: animation of a still scene", JOBS, 422, animation(), "no animation"),
    C("job: frames empty", JOBS, 422, call("POST", "/v1/jobs", json={"scene_id": Ref("animated"),
      "kind": "animation", "frames": []}), "frames"),
    C("job: frames repeated", JOBS, 422, call("POST", "/v1/jobs", json={
      "scene_id": Ref("animated"), "kind": "animation", "frames": [1, 1]}), "repeat"),
    C("job: frames negative", JOBS, 422, call("POST", "/v1/jobs", json={
      "scene_id": Ref("animated"), "kind": "animation", "frames": [-1]}), "frames"),
    C("job: frames out of range", JOBS, 422, call("POST", "/v1/jobs", json={
      "scene_id": Ref("animated"), "kind": "animation", "frames": [0, 99]}), "frames"),
    C("job: frames huge number", JOBS, 422, call("POST", "/v1/jobs", json={
      "scene_id": Ref("animated"), "kind": "animation", "frames": [10**30]}), "frames"),
    C("job: 400k frames", JOBS, 422, call("POST", "/v1/jobs", 60.0, json={
      "scene_id": Ref("animated"), "kind": "animation", "frames": list(range(400_000))}),
      heavy=True, quick=False),
    C("job: camera_path of 1001 poses", JOBS, 422, animation(camera_path=[POSE] * 1001),
      "frames"),
    C("job: camera_path of 20k poses", JOBS, 422, many_poses(20_000), "at most 10000"),
    C("job: camera_path of 400k poses", JOBS, 413, many_poses(400_000), "limit", heavy=True,
      quick=False),
    C("job: camera_path pose at its look_at", JOBS, 422, animation(camera_path=[
      {"position": [0, 0, 0], "look_at": [0, 0, 0]}]), "look_at"),
    C("job: camera vfov 180", JOBS, 422, job(camera={**POSE, "vfov_deg": 180}), "vfov"),
    C("job: camera position of 2 numbers", JOBS, 422, job(camera={"position": [0, 1],
      "look_at": [0, 0, 0]}), "position"),
    C("job: body nested 100k deep", JOBS, 400, json_bytes(
      '{"scene_id": "x", "camera": ' + deep(100_000) + "}")),
    C("job: malformed JSON", JOBS, 400, json_bytes('{"scene_id": ')),
    C("job: JSON then garbage", JOBS, 400, json_bytes('{"scene_id": "x"} trailing')),
    C("job: not UTF-8", JOBS, 400, call("POST", "/v1/jobs", content=b'{"scene_id": "\xff\xfe"}',
      headers=JSON)),
    C("job: a JSON array", JOBS, 422, call("POST", "/v1/jobs", json=[1, 2, 3])),
    C("job: JSON sent as text/plain", JOBS, 422, call("POST", "/v1/jobs",
      content=b'{"scene_id": "x"}', headers={"content-type": "text/plain"})),
]  # fmt: skip

READ_CASES = [
    C("jobs: limit 0", "GET /v1/jobs", 422, call("GET", "/v1/jobs", params={"limit": 0}),
      "limit"),
    C("jobs: limit 10**6", "GET /v1/jobs", 422, call("GET", "/v1/jobs",
      params={"limit": 10**6}), "limit"),
    C("jobs: offset -1", "GET /v1/jobs", 422, call("GET", "/v1/jobs", params={"offset": -1}),
      "offset"),
    C("jobs: limit not a number", "GET /v1/jobs", 422, call("GET", "/v1/jobs",
      params={"limit": "all"}), "limit"),
    C("jobs: unknown status", "GET /v1/jobs", 422, call("GET", "/v1/jobs",
      params={"status": "lost"}), "status"),
    C("job: unknown id", "GET /v1/jobs/{id}", 404, call("GET", "/v1/jobs/j000000000000"),
      "no job"),
    C("job: 5000-character id", "GET /v1/jobs/{id}", 404, call("GET", "/v1/jobs/" + "j" * 5000),
      "no job"),
    C("cancel: unknown job", "POST /v1/jobs/{id}/cancel", 404, call("POST",
      "/v1/jobs/j000000000000/cancel"), "no job"),
    C("cancel: finished job", "POST /v1/jobs/{id}/cancel", 409, call("POST",
      "/v1/jobs/{done_job}/cancel"), "already"),
    C("frame: not finished", "GET /v1/jobs/{id}/frames/{n}", 404, call("GET",
      "/v1/jobs/{done_job}/frames/7"), "no finished frame"),
    C("frame: -1", "GET /v1/jobs/{id}/frames/{n}", 422, call("GET",
      "/v1/jobs/{done_job}/frames/-1"), "frame"),
    C("frame: 10**12", "GET /v1/jobs/{id}/frames/{n}", 422, call("GET",
      "/v1/jobs/{done_job}/frames/1000000000000"), "frame"),
    C("result: format tiff", "GET /v1/jobs/{id}/result", 422, call("GET",
      "/v1/jobs/{done_job}/result", params={"format": "tiff"}), "format"),
    C("result: npy (valid)", "GET /v1/jobs/{id}/result", 200, call("GET",
      "/v1/jobs/{done_job}/result", params={"format": "npy"})),
    C("events: unknown job", "GET /v1/jobs/{id}/events", 404, call("GET",
      "/v1/jobs/j000000000000/events"), "no job"),
    C("scene: unknown", "GET /v1/scenes/{id}", 404, call("GET", f"/v1/scenes/{MISSING}"),
      "no scene"),
    C("scene: id with an encoded slash", "GET /v1/scenes/{id}", 404, call("GET",
      "/v1/scenes/..%2F..%2Fetc%2Fpasswd")),
    C("scene: delete unknown", "DELETE /v1/scenes/{id}", 404, call("DELETE",
      f"/v1/scenes/{MISSING}"), "no scene"),
    C("path: unknown", "GET /v1/nothing", 404, call("GET", "/v1/nothing")),
    C("balancer: unknown", "PUT /v1/cluster/balancer", 422, call("PUT", "/v1/cluster/balancer",
      json={"name": "fastest"}), "unknown balancer"),
    C("balancer: 10k-character name", "PUT /v1/cluster/balancer", 422, call("PUT",
      "/v1/cluster/balancer", json={"name": "b" * 10_000}), "name"),
]  # fmt: skip

QUERY_CASES = [
    C("query: nothing", QUERY, 422, query(), "either"),
    C("query: ray and pixel", QUERY, 422, query(origin=[0, 0, 0], direction=[0, 0, 1], x=1, y=1),
      "either"),
    C("query: zero direction", QUERY, 422, query(origin=[0, 1, 4], direction=[0, 0, 0]), "zero"),
    C("query: NaN direction", QUERY, 422, call("POST", "/v1/scenes/{scene}/query",
      content=b'{"origin": [0, 1, 4], "direction": [NaN, 0, -1]}', headers=JSON)),
    C("query: origin of 4 numbers", QUERY, 422, query(origin=[0, 1, 4, 5], direction=[0, 0, -1]),
      "origin"),
    C("query: pixel outside", QUERY, 422, query(x=500, y=1), "outside"),
    C("query: pixel negative", QUERY, 422, query(x=-1, y=1), "x"),
    C("query: image width 0", QUERY, 422, query(x=1, y=1, width=0), "width"),
    C("query: unknown scene", QUERY, 404, call("POST", f"/v1/scenes/{MISSING}/query",
      json={"x": 1, "y": 1}), "no scene"),
    C("query: far ray (valid, a miss)", QUERY, 200, query(origin=[0, 1e6, 0],
      direction=[0, 1, 0])),
]  # fmt: skip

SESSION_CASES = [
    C("session: unknown scene", "POST /v1/sessions", 404, call("POST", "/v1/sessions",
      json={"scene_id": MISSING}), "no scene"),
    C("session: width 7", "POST /v1/sessions", 422, session(width=7), "width"),
    C("session: over the resolution limit", "POST /v1/sessions", 422, session(width=9000,
      height=100), "resolution"),
    C("session: 4K (over the session size limit)", "POST /v1/sessions", 422, session(
      width=3840, height=2160)),
    C("session: target_fps 0", "POST /v1/sessions", 422, session(target_fps=0), "target_fps"),
    C("session: target_fps 1000", "POST /v1/sessions", 422, session(target_fps=1000),
      "target_fps"),
    C("session: min_blend 2", "POST /v1/sessions", 422, session(min_blend=2), "min_blend"),
    C("session: opened at its look_at", "POST /v1/sessions", 422, session(camera={
      "position": [0, 0, 0], "look_at": [0, 0, 0]}), "look_at"),
    C("session: unknown field", "POST /v1/sessions", 422, session(fps=5), "unknown field"),
    C("session: unknown", "GET /v1/sessions/{id}", 404, call("GET",
      "/v1/sessions/v000000000000"), "no session"),
    C("session: close unknown", "DELETE /v1/sessions/{id}", 404, call("DELETE",
      "/v1/sessions/v000000000000"), "no session"),
    C("session: frame of unknown", "GET /v1/sessions/{id}/frame.jpg", 404, call("GET",
      "/v1/sessions/v000000000000/frame.jpg"), "no session"),
    C("session: stream of unknown", "GET /v1/sessions/{id}/stream", 404, call("GET",
      "/v1/sessions/v000000000000/stream"), "no session"),
    C("session: camera of unknown", "PUT /v1/sessions/{id}/camera", 404, call("PUT",
      "/v1/sessions/v000000000000/camera", json=POSE), "no session"),
    C("session: camera at its look_at", "PUT /v1/sessions/{id}/camera", 422, on_session("PUT",
      "/camera", json={"position": [0, 0, 0], "look_at": [0, 0, 0]}), "look_at"),
    C("session: camera NaN", "PUT /v1/sessions/{id}/camera", 422, on_session("PUT", "/camera",
      content=b'{"position": [NaN, 0, 0], "look_at": [0, 0, 0]}', headers=JSON)),
    C("session: camera with a width", "PUT /v1/sessions/{id}/camera", 422, on_session("PUT",
      "/camera", json={**POSE, "width": 3840}), "unknown field"),
    C("session: frame after -1 (valid)", "GET /v1/sessions/{id}/frame.jpg", 200, on_session(
      "GET", "/frame.jpg", params={"after": -1})),
]  # fmt: skip

METHOD_CASES = [
    C(f"method: {method} {path}", "a wrong method", 405, call(method, path.format(
      scene="{scene}", job="{done_job}")), allow=allow)
    for method, path, allow in [
        ("PUT", "/v1/scenes", methods("GET", "POST")),
        ("POST", "/v1/scenes/{scene}", methods("GET", "DELETE", "PATCH")),
        ("GET", "/v1/scenes/{scene}/commits", methods("POST")),
        ("DELETE", "/v1/jobs", methods("GET", "POST")),
        ("PATCH", "/v1/jobs/{job}", methods("GET")),
        ("GET", "/v1/jobs/{job}/cancel", methods("POST")),
        ("DELETE", "/v1/sessions", methods("GET", "POST")),
        ("POST", "/v1/sessions/v000000000000/camera", methods("PUT")),
        ("GET", "/v1/cluster/balancer", methods("PUT")),
        ("POST", "/healthz", methods("GET")),
    ]
]  # fmt: skip

WIRE_CASES = [
    C("wire: Content-Length not a number", "POST /v1/jobs", 400, raw(
      "POST /v1/jobs HTTP/1.1\nHost: {host}\nContent-Type: application/json\n"
      "Content-Length: lots"), json_error=False),
    C("wire: Content-Length 100 MB, no body", "POST /v1/scenes", 413, raw(
      "POST /v1/scenes HTTP/1.1\nHost: {host}\nContent-Type: application/json\n"
      "Content-Length: 100000000"), "limit"),
    C("wire: body cut short, the client leaves", "POST /v1/jobs", None, raw(
      "POST /v1/jobs HTTP/1.1\nHost: {host}\nContent-Type: application/json\n"
      "Content-Length: 1000", b'{"scene_id": "', shut_write=True)),
    C("wire: body stalls after 14 bytes", "POST /v1/jobs", 408, raw(
      "POST /v1/jobs HTTP/1.1\nHost: {host}\nContent-Type: application/json\n"
      "Content-Length: 1000", b'{"scene_id": "', timeout=40.0), quick=False),
    C("wire: chunked body over the limit", "POST /v1/scenes", 413, call("POST", "/v1/scenes",
      content=iter([b" " * MiB] * 65), headers=JSON), "limit", heavy=True, quick=False),
]  # fmt: skip

API_CASES = (
    COMMIT_CASES + JOB_CASES + READ_CASES + QUERY_CASES + SESSION_CASES + METHOD_CASES
    + WIRE_CASES
)  # fmt: skip

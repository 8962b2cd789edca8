"""The hostile corpus, uploads (``POST /v1/scenes``): JSON scenes, multipart bodies, zip
bundles, OBJ/MTL and glTF/GLB files, and the auth cases (run against a server with a token).
The shapes of a case are ``hostile_cases.py``'s."""

import json
import struct

from bench.load.hostile_cases import JSON, Case, MiB, Send, call, many_poses, raw
from tests.helpers import tiny_scene, zip_bytes

C = Case
UPLOAD = "POST /v1/scenes"
TOKEN = "hostile-corpus-token"

RENDER = {"spp": 1, "max_depth": 4, "rr_depth": 2, "seed": 1}


def scene(**changes) -> dict:
    """A small valid scene of built-in shapes (12x8 pixels, 1 spp), with ``changes``."""
    return tiny_scene(**{"render": RENDER, **changes})


SCENE = scene()


def animated_scene() -> dict:
    out = scene()
    out["objects"][1]["kind"] = "rigid"
    out["animation"] = {
        "fps": 4,
        "frames": 4,
        "objects": {"cube": [{"time": 0}, {"time": 1, "translate": [1, 0.5, 0]}]},
    }
    return out


def scene_bytes(**changes) -> bytes:
    return json.dumps(scene(**changes)).encode()


def with_object(**changes) -> bytes:
    """The scene with its cube changed."""
    out = scene()
    out["objects"][1].update(changes)
    return json.dumps(out).encode()


def with_mesh(path: str) -> bytes:
    """The scene with its cube replaced by the mesh file ``path``."""
    return with_object(shape=path)


TRI = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"
OBJ_FLAT = b"v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n"
OBJ_EMPTY = b"v 0 0 0\nv 1 0 0\nv 0 1 0\n"
OBJ_NAN = b"v nan 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"
OBJ_FAR = b"v 1e38 0 0\nv 1.00001e38 0 0\nv 1e38 1e33 0\nf 1 2 3\n"
MTL_OUT = b"newmtl m\nKd 1 1 1\nmap_Kd ../../../etc/x.png\n"


def _patch_headers(data: bytes, name: bytes, local: tuple, central: tuple) -> bytes:
    """Overwrite a field of ``name``'s local header and central directory record: ``local``
    and ``central`` are (offset, struct format, value)."""
    out = bytearray(data)
    for signature, length_at, name_at, (offset, form, value) in (
        (b"PK\x03\x04", 26, 30, local),
        (b"PK\x01\x02", 28, 46, central),
    ):
        start = 0
        while (start := out.find(signature, start)) >= 0:
            length = struct.unpack_from("<H", out, start + length_at)[0]
            if out[start + name_at : start + name_at + length] == name:
                struct.pack_into(form, out, start + offset, value)
            start += 4
    return bytes(out)


def encrypted_zip() -> bytes:
    """A bundle whose scene.json says it is encrypted (general purpose flag bit 0)."""
    data = zip_bytes({"scene.json": scene_bytes()})
    return _patch_headers(data, b"scene.json", (6, "<H", 1), (8, "<H", 1))


def lying_zip() -> bytes:
    """A zip whose entry declares 100 bytes and holds 4 MiB (its headers patched): unpacking
    must stop at what it declares."""
    data = zip_bytes({"scene.json": scene_bytes(), "pad.bin": b"\0" * (4 * MiB)})
    return _patch_headers(data, b"pad.bin", (22, "<I", 100), (24, "<I", 100))


def glb(document: bytes, length: int | None = None) -> bytes:
    """A binary glTF with ``document`` as its JSON chunk (no BIN chunk)."""
    document += b" " * (-len(document) % 4)
    chunk = struct.pack("<I4s", len(document), b"JSON") + document
    total = 12 + len(chunk) if length is None else length
    return struct.pack("<4sII", b"glTF", 2, total) + chunk


def gltf(uri: str, section: str = "buffers") -> bytes:
    item = {"uri": uri, "byteLength": 36} if section == "buffers" else {"uri": uri}
    return json.dumps({"asset": {"version": "2.0"}, section: [item], "meshes": []}).encode()


def upload(**files) -> Send:
    return call("POST", "/v1/scenes", files=files)


def raw_json(body: bytes, **headers) -> Send:
    return call("POST", "/v1/scenes", content=body, headers={**JSON, **headers})


def bundle(entries: dict[str, bytes], **kwargs) -> Send:
    return upload(bundle=("b.zip", zip_bytes(entries, **kwargs)))


def obj_bundle(obj: bytes, **more: bytes) -> Send:
    """A bundle of the scene with its cube as ``m.obj`` and ``more`` files."""
    return bundle({"scene.json": with_mesh("m.obj"), "m.obj": obj, **more})


def multipart(body: bytes, boundary: str | None = "b0undary") -> Send:
    ctype = "multipart/form-data" + (f"; boundary={boundary}" if boundary else "")
    return call("POST", "/v1/scenes", content=body, headers={"content-type": ctype})


PART = b'--b0undary\r\nContent-Disposition: form-data; name="scene"; filename="s.json"\r\n\r\n'
HUGE_NAME = "x" * 100_000

UPLOAD_CASES = [
    C("upload: valid JSON scene", UPLOAD, 201, raw_json(scene_bytes())),
    C("upload: no content type", UPLOAD, 415, call("POST", "/v1/scenes", content=b"x"),
      "content type"),
    C("upload: text/plain", UPLOAD, 415, call("POST", "/v1/scenes", content=scene_bytes(),
      headers={"content-type": "text/plain"}), "content type"),
    C("upload: application/xml", UPLOAD, 415, call("POST", "/v1/scenes", content=b"<scene/>",
      headers={"content-type": "application/xml"}), "content type"),
    C("upload: empty JSON body", UPLOAD, 422, raw_json(b""), "empty"),
    C("upload: JSON array", UPLOAD, 422, raw_json(b"[1, 2]")),
    C("upload: JSON null", UPLOAD, 422, raw_json(b"null")),
    C("upload: JSON cut short", UPLOAD, 422, raw_json(scene_bytes()[:40])),
    C("upload: a zip sent as JSON", UPLOAD, 422, raw_json(zip_bytes({"scene.json": b"{}"}))),
    C("upload: JSON sent as a zip", UPLOAD, 422, call("POST", "/v1/scenes",
      content=scene_bytes(), headers={"content-type": "application/zip"}), "zip"),
    C("upload: NaN", UPLOAD, 422, raw_json(scene_bytes().replace(b"45.0", b"NaN")),
      "non-finite"),
    C("upload: Infinity", UPLOAD, 422, raw_json(scene_bytes().replace(b"45.0", b"Infinity"))),
    C("upload: 1e999", UPLOAD, 422, raw_json(scene_bytes().replace(b"45.0", b"1e999"))),
    C("upload: spp of 5000 digits", UPLOAD, 422, raw_json(scene_bytes().replace(
      b'"spp": 1', b'"spp": 1' + b"0" * 5000))),
    C("upload: nested 100k deep", UPLOAD, 422, raw_json(scene_bytes().replace(
      b'"format"', b'"deep": ' + b"[" * 100_000 + b"]" * 100_000 + b', "format"'))),
    C("upload: unknown key", UPLOAD, 422, raw_json(scene_bytes(colour=1)), "unknown key"),
    C("upload: cube 1e38 away", UPLOAD, 422, raw_json(with_object(transform={
      "translate": [1e38, 0.5, 0]}))),
    C("upload: camera 1e38 away (valid: renders black)", UPLOAD, 201, raw_json(scene_bytes(camera={
      **SCENE["camera"], "position": [1e38, 0, 0]}))),
    C("upload: box of size 0", UPLOAD, 422, raw_json(with_object(shape={"type": "box",
      "size": [0, 0, 0]}))),
    C("upload: 100k-character material name", UPLOAD, 422, raw_json(json.dumps(scene(
      materials={**SCENE["materials"], HUGE_NAME: {"reflectance": [1, 1, 1]}})).encode())),
    C("upload: 100k-character object name", UPLOAD, 422, raw_json(with_object(name=HUGE_NAME))),
    C("upload: 5000-character name query", UPLOAD, 422, call("POST", "/v1/scenes",
      params={"name": "n" * 5000}, content=scene_bytes(), headers=JSON), "name"),
    C("upload: unicode names (valid)", UPLOAD, 201, call("POST", "/v1/scenes",
      params={"name": "Szene ü 場景"}, content=with_object(name="würfel-立方体"), headers=JSON)),
    C("upload: missing mesh file", UPLOAD, 422, raw_json(with_mesh("missing.obj")),
      "no such file"),
    C("upload: reference ../", UPLOAD, 422, raw_json(with_mesh("../etc/passwd.obj"))),
    C("upload: absolute reference", UPLOAD, 422, raw_json(with_mesh("/etc/passwd.obj"))),
    C("upload: 64 MiB + 1 body", UPLOAD, 413, raw_json(b" " * (64 * MiB + 1)), "limit",
      heavy=True, quick=False),
    # multipart
    C("multipart: no boundary", UPLOAD, 400, multipart(PART + b"{}\r\n--b0undary--\r\n", None)),
    # A part without its closing boundary never completes: the form has no scene (422).
    C("multipart: cut short", UPLOAD, 422, multipart(PART + scene_bytes()[:30])),
    C("multipart: 300 files", UPLOAD, 400, call("POST", "/v1/scenes", files=[("scene",
      ("s.json", scene_bytes()))] + [("files", (f"f{i}.obj", TRI)) for i in range(300)])),
    C("multipart: 20 name fields", UPLOAD, 400, call("POST", "/v1/scenes", files=[("scene",
      ("s.json", scene_bytes()))], data={"name": [f"n{i}" for i in range(20)]})),
    C("multipart: nothing to upload", UPLOAD, 422, call("POST", "/v1/scenes",
      data={"name": "x"}, files={"files": ("a.obj", TRI)}), "exactly one"),
    C("multipart: scene and mesh", UPLOAD, 422, upload(scene=("s.json", scene_bytes()),
      mesh=("a.obj", TRI)), "exactly one"),
    C("multipart: unknown field", UPLOAD, 422, upload(scene=("s.json", scene_bytes()),
      extra=("x", b"1")), "unknown form field"),
    C("multipart: scene twice", UPLOAD, 422, call("POST", "/v1/scenes", files=[
      ("scene", ("a.json", scene_bytes())), ("scene", ("b.json", scene_bytes()))])),
    C("multipart: files as a text field", UPLOAD, 422, call("POST", "/v1/scenes",
      files={"scene": ("s.json", scene_bytes())}, data={"files": "m.obj"}), "files"),
    C("multipart: 201-character name", UPLOAD, 422, call("POST", "/v1/scenes",
      files={"scene": ("s.json", scene_bytes())}, data={"name": "n" * 201}), "name"),
    C("multipart: file ../evil.obj", UPLOAD, 422, upload(scene=("s.json", scene_bytes()),
      files=("../evil.obj", TRI)), ".."),
    C("multipart: file /tmp/evil.obj", UPLOAD, 422, upload(scene=("s.json", scene_bytes()),
      files=("/tmp/evil.obj", TRI)), "absolute"),
    C("multipart: file ..\\evil.obj", UPLOAD, 422, upload(scene=("s.json", scene_bytes()),
      files=("..\\evil.obj", TRI)), "backslash"),
    C("multipart: file C:evil.obj", UPLOAD, 422, upload(scene=("s.json", scene_bytes()),
      files=("C:evil.obj", TRI)), "absolute"),
    C("multipart: file name with a control character", UPLOAD, 422, multipart(PART
      + scene_bytes() + b'\r\n--b0undary\r\nContent-Disposition: form-data; name="files"; '
      b'filename="a\x07.obj"\r\n\r\n' + TRI + b"\r\n--b0undary--\r\n"), "control"),
    C("multipart: file named scene.json", UPLOAD, 422, upload(scene=("s.json", scene_bytes()),
      files=("scene.json", b"{}")), "scene.json"),
    C("multipart: same file twice", UPLOAD, 422, call("POST", "/v1/scenes", files=[
      ("scene", ("s.json", with_mesh("m.obj"))), ("files", ("m.obj", TRI)),
      ("files", ("m.obj", TRI))]), "twice"),
    C("multipart: mesh in a subfolder (valid)", UPLOAD, 201, call("POST", "/v1/scenes", files=[
      ("scene", ("s.json", with_mesh("meshes/m.obj"))), ("files", ("meshes/m.obj", TRI))])),
    # single mesh files
    C("mesh: unknown type", UPLOAD, 422, upload(mesh=("notes.txt", b"hello")),
      "unknown mesh type"),
    C("mesh: garbage OBJ", UPLOAD, 422, upload(mesh=("bad.obj", b"v 1 2\nf 9 9 9\n")), "bad.obj"),
    C("mesh: empty file", UPLOAD, 422, upload(mesh=("empty.stl", b"")), "empty.stl"),
    C("mesh: OBJ without faces", UPLOAD, 422, upload(mesh=("v.obj", OBJ_EMPTY))),
    C("mesh: OBJ of zero-area triangles", UPLOAD, 422, upload(mesh=("flat.obj", OBJ_FLAT))),
    C("mesh: OBJ with NaN", UPLOAD, 422, upload(mesh=("nan.obj", OBJ_NAN))),
    C("mesh: OBJ 1e38 away", UPLOAD, 422, upload(mesh=("far.obj", OBJ_FAR))),
    C("mesh: OBJ mtllib ../", UPLOAD, 422, upload(mesh=("m.obj", b"mtllib ../x.mtl\n" + TRI)),
      ".."),
    C("mesh: OBJ mtllib after a tab", UPLOAD, 422, upload(mesh=("m.obj",
      b"mtllib\t../../x.mtl\n" + TRI))),
    C("mesh: OBJ mtllib inside a comment", UPLOAD, 422, upload(mesh=("m.obj",
      b"# see mtllib ../../x.mtl\n" + TRI))),
    C("mesh: glTF buffer ../", UPLOAD, 422, upload(mesh=("m.gltf", gltf("../../etc/passwd"))),
      ".."),
    C("mesh: glTF buffer percent-encoded ../", UPLOAD, 422, upload(mesh=("m.gltf",
      gltf("%2e%2e/%2e%2e/etc/passwd")))),
    C("mesh: glTF image absolute", UPLOAD, 422, upload(mesh=("m.gltf",
      gltf("/etc/passwd", "images"))), "absolute"),
    C("mesh: glTF image file:// URI", UPLOAD, 422, upload(mesh=("m.gltf",
      gltf("file:///etc/passwd", "images")))),
    C("mesh: glTF not JSON", UPLOAD, 422, upload(mesh=("m.gltf", b"{nope"))),
    C("mesh: GLB garbage", UPLOAD, 422, upload(mesh=("x.glb", b"glTF\x02\x00\x00\x00garbage")),
      "x.glb"),
    C("mesh: GLB JSON chunk not JSON", UPLOAD, 422, upload(mesh=("x.glb", glb(b"{nope")))),
    C("mesh: GLB buffer ../", UPLOAD, 422, upload(mesh=("x.glb", glb(gltf("../../etc/passwd"))))),
    C("mesh: GLB image absolute", UPLOAD, 422, upload(mesh=("x.glb",
      glb(gltf("/etc/passwd", "images"))))),
    C("mesh: GLB declaring 2 GB", UPLOAD, 422, upload(mesh=("x.glb",
      glb(gltf("data:,"), 2**31)))),
    # bundles
    C("bundle: not a zip", UPLOAD, 422, upload(bundle=("b.zip", b"PK not really")), "zip"),
    C("bundle: cut in half", UPLOAD, 422, upload(bundle=("b.zip", zip_bytes({
      "scene.json": scene_bytes()})[:200])), "zip"),
    C("bundle: empty zip", UPLOAD, 422, bundle({})),
    C("bundle: entry ../scene.json", UPLOAD, 422, bundle({"../scene.json": scene_bytes()}), ".."),
    C("bundle: entry a/../../x", UPLOAD, 422, bundle({"scene.json": scene_bytes(),
      "a/../../x.obj": TRI}), ".."),
    C("bundle: absolute entry", UPLOAD, 422, bundle({"/scene.json": scene_bytes()}),
      "absolute"),
    C("bundle: drive-letter entry", UPLOAD, 422, bundle({"C:/scene.json": scene_bytes()}),
      "absolute"),
    C("bundle: symlink", UPLOAD, 422, bundle({"scene.json": with_mesh("m.obj")},
      links={"m.obj": "/etc/passwd"}), "link"),
    C("bundle: encrypted entry", UPLOAD, 422, upload(bundle=("b.zip", encrypted_zip())),
      "encrypted"),
    C("bundle: same name in two cases", UPLOAD, 422, bundle({"scene.json": scene_bytes(),
      "M.obj": TRI, "m.obj": TRI}), "twice"),
    C("bundle: 2000-character path", UPLOAD, 422, bundle({"scene.json": scene_bytes(),
      "d/" * 1000 + "m.obj": TRI})),
    C("bundle: zip bomb by ratio", UPLOAD, 413, bundle({"scene.json": scene_bytes(),
      "pad.bin": b"\0" * (4 * MiB)}), "zip bomb"),
    C("bundle: entry larger than it declares", UPLOAD, 422, upload(bundle=("b.zip",
      lying_zip()))),
    C("bundle: 300 entries", UPLOAD, 413, bundle({"scene.json": scene_bytes()}
      | {f"f{i}.txt": b"x" for i in range(300)}), "entries"),
    C("bundle: no scene", UPLOAD, 422, bundle({"a.txt": b"1", "b.txt": b"2"}), "no scene.json"),
    C("bundle: two JSON files", UPLOAD, 422, bundle({"a.json": b"{}", "b.json": b"{}"}),
      "several"),
    C("bundle: raw zip traversal", UPLOAD, 422, call("POST", "/v1/scenes", content=zip_bytes(
      {"a/../../x.json": b"{}"}), headers={"content-type": "application/zip"}), ".."),
    C("bundle: MTL map_Kd ../", UPLOAD, 422, obj_bundle(b"mtllib m.mtl\n" + TRI,
      **{"m.mtl": MTL_OUT}), ".."),
    C("bundle: MTL MAP_KD ../ in capitals", UPLOAD, 422, obj_bundle(b"mtllib m.mtl\n" + TRI,
      **{"m.mtl": MTL_OUT.replace(b"map_Kd", b"MAP_KD")})),
    C("bundle: MTL map_Kd after a tab", UPLOAD, 422, obj_bundle(b"mtllib m.mtl\n" + TRI,
      **{"m.mtl": MTL_OUT.replace(b"map_Kd ", b"map_Kd\t")})),
    C("bundle: mtllib not named .mtl", UPLOAD, 422, obj_bundle(b"mtllib m.txt\n" + TRI,
      **{"m.txt": MTL_OUT})),
    C("bundle: OBJ with its MTL inside (valid)", UPLOAD, 201, obj_bundle(b"mtllib m.mtl\n" + TRI,
      **{"m.mtl": b"newmtl m\nKd 1 1 1\n"})),
]  # fmt: skip

SECRET = f"Bearer {TOKEN}"
UNAUTHENTICATED_HEAD = (
    "POST {path} HTTP/1.1\nHost: {{host}}\nContent-Type: {ctype}\nContent-Length: 50000000"
)

AUTH_CASES = [
    C("auth: no token", "GET /v1/scenes", 401, call("GET", "/v1/scenes"), "token"),
    C("auth: Basic scheme", "GET /v1/scenes", 401, call("GET", "/v1/scenes",
      headers={"Authorization": "Basic YTpi"}), "Bearer"),
    C("auth: empty Bearer", "GET /v1/scenes", 401, call("GET", "/v1/scenes",
      headers={"Authorization": "Bearer"})),
    C("auth: wrong token", "GET /v1/scenes", 403, call("GET", "/v1/scenes",
      headers={"Authorization": "Bearer wrong-token"}), "not valid"),
    C("auth: wrong access_token", "GET /v1/scenes", 403, call("GET", "/v1/scenes",
      params={"access_token": "wrong-token"}), "not valid"),
    C("auth: the token (valid)", "GET /v1/scenes", 200, call("GET", "/v1/scenes",
      headers={"Authorization": SECRET})),
    C("auth: access_token (valid)", "GET /v1/scenes", 200, call("GET", "/v1/scenes",
      params={"access_token": TOKEN})),
    C("auth: /healthz stays open (valid)", "GET /healthz", 200, call("GET", "/healthz")),
    C("auth: 56 MB JSON without a token", UPLOAD, 401, raw_json(b" " * (56 * MiB)),
      heavy=True),
    C("auth: 56 MB multipart with a wrong token", UPLOAD, 403, call("POST", "/v1/scenes",
      files={"scene": ("s.json", b" " * (56 * MiB))},
      headers={"Authorization": "Bearer wrong-token"}), heavy=True),
    C("auth: 400k poses without a token", "POST /v1/jobs", 401, many_poses(400_000),
      heavy=True),
    C("auth: upload headers alone, no token", UPLOAD, 401, raw(UNAUTHENTICATED_HEAD.format(
      path="/v1/scenes", ctype="application/json"), b" " * 1024)),
    C("auth: job headers alone, no token", "POST /v1/jobs", 401, raw(
      UNAUTHENTICATED_HEAD.format(path="/v1/jobs", ctype="application/json"), b"{" * 1024)),
    C("auth: multipart headers alone, no token", UPLOAD, 401, raw(UNAUTHENTICATED_HEAD.format(
      path="/v1/scenes", ctype="multipart/form-data; boundary=b0undary"), PART)),
]  # fmt: skip
AUTH_CASES = [Case(**{**c.__dict__, "auth": True}) for c in AUTH_CASES]

"""Paths inside an upload: the names a client gives, the files its meshes reference, and error
messages that name only those.

A name is refused (ApiError 422) if it is absolute, has a drive letter, ``..``, a backslash or
a control character. Every file a mesh references must be a file of the upload, and the
references are found the way the installed trimesh reads them (``trimesh.exchange``), since
trimesh is what opens them:

- OBJ: the first ``mtllib`` anywhere in the text (after trimesh's line joining), the rest of
  that line as one name; the file it names is then read as MTL, whatever it is called;
- MTL: each line whose first word is ``map_Kd`` in any case, the rest of the line as one name
  (read by trimesh's own ``parse_mtl``), taken from the OBJ's directory as trimesh does;
- PLY: the header's ``TextureFile`` comment (read by trimesh's own header parser);
- glTF, and GLB's JSON chunk: every buffer and image ``uri`` that is not ``base64,`` data.

trimesh 5 (the version ``pyproject.toml`` requires) also refuses names that leave a mesh's
directory; these checks do not rely on that, and answer with a clear message where trimesh
would drop a texture silently.
"""

import json
import re
import struct
from pathlib import Path, PurePosixPath
from urllib.parse import unquote

from api.errors import ApiError

MAX_NAME = 255
MAX_PATH = 1024
GLB_MAGIC = b"glTF"
GLB_JSON = 0x4E4F534A

_DRIVE = re.compile(r"^[A-Za-z]:")


def safe_relative(name: str, what: str = "file") -> PurePosixPath:
    """``name`` as a relative path that stays inside its directory; ApiError 422 otherwise."""
    if not isinstance(name, str) or not name.strip():
        raise ApiError(422, f"{what}: an empty file name", "unsafe_path")
    if "\x00" in name or any(ord(c) < 32 for c in name):
        raise ApiError(422, f"{what} {name!r}: control characters in a file name", "unsafe_path")
    if "\\" in name:
        raise ApiError(422, f"{what} {name!r}: backslashes are not allowed in paths", "unsafe_path")
    if name.startswith("/") or _DRIVE.match(name):
        raise ApiError(422, f"{what} {name!r}: absolute paths are not allowed", "unsafe_path")
    if len(name) > MAX_PATH:
        raise ApiError(422, f"{what}: a path longer than {MAX_PATH} characters", "unsafe_path")
    path = PurePosixPath(name)
    parts = [p for p in path.parts if p not in ("", ".")]
    if not parts:
        raise ApiError(422, f"{what} {name!r}: not a file name", "unsafe_path")
    if ".." in parts:
        raise ApiError(422, f"{what} {name!r}: '..' may not appear in paths", "unsafe_path")
    if any(len(p) > MAX_NAME for p in parts):
        raise ApiError(422, f"{what} {name!r}: a path component is too long", "unsafe_path")
    return PurePosixPath(*parts)


def inside(root: Path, relative: PurePosixPath) -> Path:
    """The path ``relative`` names under ``root``; ApiError 422 if it resolves outside it."""
    target = (root / Path(*relative.parts)).resolve()
    if not target.is_relative_to(root.resolve()):
        raise ApiError(422, f"{relative}: leaves the scene's directory", "unsafe_path")
    return target


# --- References --------------------------------------------------------------------------


def _reference(root: Path, base: Path, names: list[str], where: str) -> Path | None:
    """The upload's file a reference names: ``names`` are its readings (trimesh's resolver
    strips each), all of which must be safe, relative to ``base``; ApiError 422 unless one is
    a file of the upload. None for an empty name (trimesh then reads nothing)."""
    readings = [name.strip() for name in names]
    if not readings[0]:
        return None
    targets = []
    for reading in readings:
        relative = safe_relative(reading, where)
        targets.append(inside(root, PurePosixPath(*base.relative_to(root).parts, *relative.parts)))
    found = next((t for t in targets if t.is_file()), None)
    if found is None:
        raise ApiError(422, f"{where} {readings[0]!r}: no such file in the upload", "missing_file")
    return found


def obj_material_library(data: bytes) -> str | None:
    """The ``mtllib`` name an OBJ gives, found as ``trimesh.exchange.obj.load_obj`` finds it:
    the first occurrence in the whole text, the rest of its line."""
    from trimesh import util

    text = "\n{}\n".format(util.decode_text(data).strip().replace("\r\n", "\n"))
    text = text.replace("\\\n", "")
    position = text.find("mtllib")
    if position < 0:
        return None
    return text[position + 6 : text.find("\n", position)].strip()


class _Recorder:
    """A trimesh resolver that notes each name asked for and serves none."""

    def __init__(self) -> None:
        self.names: list[str] = []

    def get(self, name: str) -> bytes:
        self.names.append(name)
        raise FileNotFoundError(name)

    __getitem__ = get


def mtl_textures(data: bytes) -> list[str]:
    """The texture names trimesh's own ``parse_mtl`` reads from an MTL file."""
    from trimesh.exchange.obj import parse_mtl

    recorder = _Recorder()
    try:
        parse_mtl(data, resolver=recorder)
    except Exception:  # trimesh then drops the materials; what it asked for is recorded
        pass
    return recorder.names


def ply_texture(path: Path) -> str | None:
    """The ``TextureFile`` name trimesh's own PLY header parser reads (None if none, or if
    trimesh cannot read the header, when it reads nothing else)."""
    from trimesh.exchange.ply import _parse_header

    try:
        with open(path, "rb") as f:
            return _parse_header(f)[2]
    except Exception:  # not a PLY header trimesh can read: loading it fails before any texture
        return None


def gltf_document(path: Path, name: str) -> dict:
    """The JSON of a ``.gltf`` file, or of a ``.glb`` file's first chunk; ApiError 422 if
    there is none."""
    data = path.read_bytes()
    if path.suffix.lower() == ".glb":
        if len(data) < 20 or data[:4] != GLB_MAGIC:
            raise ApiError(422, f"{name}: not a GLB file", "invalid_scene")
        length, kind = struct.unpack_from("<II", data, 12)
        if kind != GLB_JSON:
            raise ApiError(422, f"{name}: the GLB file does not start with JSON", "invalid_scene")
        data = data[20 : 20 + length]
    try:
        doc = json.loads(data.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError, RecursionError):
        raise ApiError(422, f"{name}: not valid glTF JSON", "invalid_scene") from None
    if not isinstance(doc, dict):
        raise ApiError(422, f"{name}: not valid glTF JSON", "invalid_scene")
    return doc


def check_references(root: Path) -> None:
    """Refuse mesh files under ``root`` that reference anything but files of the upload
    (module docstring)."""
    for path in sorted(p for p in root.rglob("*") if p.is_file()):
        suffix = path.suffix.lower()
        name = str(path.relative_to(root))
        base = path.parent
        if suffix in (".gltf", ".glb"):
            doc = gltf_document(path, name)
            for section in ("buffers", "images"):
                items = doc.get(section)
                for item in items if isinstance(items, list) else []:
                    uri = item.get("uri") if isinstance(item, dict) else None
                    if isinstance(uri, str) and "base64," not in uri:
                        # trimesh opens the URI as written; a percent-decoded reading must be
                        # safe too
                        _reference(root, base, [uri, unquote(uri)], f"{name}: {section} uri")
        elif suffix == ".obj":
            library = obj_material_library(path.read_bytes())
            mtl = None if library is None else _reference(root, base, [library], f"{name}: mtllib")
            if mtl is not None:
                where = f"{name}: {mtl.relative_to(root.resolve())}: map_Kd"
                for texture in mtl_textures(mtl.read_bytes()):
                    _reference(root, base, [texture], where)
        elif suffix == ".ply":
            texture = ply_texture(path)
            if texture is not None:
                _reference(root, base, [texture], f"{name}: TextureFile")


# --- Messages ----------------------------------------------------------------------------


def client_message(message: str, data_dir: Path, upload: Path | None = None) -> str:
    """``message`` naming no path of the server's: paths inside ``upload`` (an upload's files
    directory) relative to it, and any other path under ``data_dir`` cut out."""
    for directory in (upload, data_dir):
        if directory is None:
            continue
        forms = sorted({str(directory), str(directory.resolve())}, key=len, reverse=True)
        for form in forms:
            if directory is upload:
                message = message.replace(form + "/", "").replace(form, ".")
            else:
                message = re.sub(re.escape(form) + r"[^\s'\"()]*", "(a server path)", message)
    return message

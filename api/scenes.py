"""Scenes on disk: uploads, safe bundle extraction, the live scene graphs and their commits.

Each scene has a directory ``data_dir/scenes/<id>/``::

    files/            the uploaded files (the scene JSON and the meshes it names, a bundle's
                      contents, or one mesh file), exactly as uploaded; nothing else
    state.tls         the scene at a version (tracer.scene.codec.encode_state)
    commits/N.tlc     each commit after that version (encode_commit), in version order

so a restart rebuilds the scene graph from ``state.tls`` plus the commits, without reading
the uploaded files again. Every ``COMPACT_EVERY`` commits the state is rewritten and the
commit files before it removed.

**Graphs.** Each scene's live :class:`SceneGraph` is keyed by the scene's id; one coordinator
renders every scene (and every job's private copy, keyed by the job's id), and its tracers
keep replicas of the few most recently used graphs under those keys.

**Uploads.** Paths inside a bundle or a multipart upload must be relative, stay inside the
scene's directory, and name regular files: absolute paths, drive letters, ``..``,
backslashes, NUL bytes, links, devices, duplicates and encrypted entries are refused, and so
are bundles whose entries unpack to more than ``max_unpacked_bytes``, more than
``max_bundle_files`` entries, or an entry compressed more than ``max_compression_ratio``
times (a zip bomb). Bytes are counted while extracting, not taken from the headers. The
files its meshes reference (glTF and GLB URIs, OBJ ``mtllib``, MTL ``map_Kd``, PLY
``TextureFile``, read as trimesh reads them) are checked the same way before any loader reads
them, so a scene can reference only files inside its upload (``api.upload_paths``).
"""

import collections
import dataclasses
import re
import secrets
import shutil
import stat
import threading
import zipfile
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath

import numpy as np

from api.errors import ApiError
from api.settings import Settings
from api.store import Store
from api.upload_paths import check_references, client_message, inside, safe_relative
from cluster.scene_graph import SceneGraph
from tracer.errors import SceneError
from tracer.io.files import write_atomic
from tracer.maths import portable
from tracer.scene.codec import decode_commit, decode_state, encode_commit, encode_state
from tracer.scene.loader import MESH_SUFFIXES, load_scene, load_warnings
from tracer.scene.model import SceneState
from tracer.scene.ops import Commit
from tracer.shading.lights import mean_sky_radiance

COMPACT_EVERY = 256
KEEP_COMPILED = 2
"""Scenes whose compiled form (at their current version) the repository keeps, the most
recently changed, so that a commit compiles from it incrementally, as the tracers' replicas
do: moving an object then costs milliseconds, not a rebuild of the scene."""
CHUNK = 1 << 16


@dataclass(eq=False)
class SceneEntry:
    """A scene the service holds: its record, directory and live graph."""

    id: str
    name: str
    source: str
    directory: Path
    graph: SceneGraph
    lock: threading.Lock = field(default_factory=threading.Lock)
    summary_cache: dict = field(default_factory=dict)
    commits_since_compaction: int = 0
    warnings: list[str] = field(default_factory=list)
    """What loading the uploaded scene ignored or approximated of its glTF files."""

    @property
    def version(self) -> int:
        return self.graph.version


def new_id(prefix: str) -> str:
    return prefix + secrets.token_hex(6)


# --- Bundles -------------------------------------------------------------------------------


def extract_bundle(archive: Path, root: Path, settings: Settings) -> list[str]:
    """Unpack a zip bundle into ``root`` safely (module docstring); returns the file names."""
    try:
        bundle = zipfile.ZipFile(archive)
    except (zipfile.BadZipFile, OSError, ValueError):
        raise ApiError(422, "the bundle is not a valid zip file", "bad_bundle") from None
    names: list[str] = []
    total = 0
    with bundle:
        infos = bundle.infolist()
        if len(infos) > settings.max_bundle_files:
            raise ApiError(
                413,
                f"the bundle has {len(infos)} entries, more than {settings.max_bundle_files}",
                "bundle_too_large",
            )
        declared = sum(i.file_size for i in infos)
        if declared > settings.max_unpacked_bytes:
            raise ApiError(
                413,
                f"the bundle unpacks to {declared} bytes, more than {settings.max_unpacked_bytes}",
                "bundle_too_large",
            )
        seen: set[str] = set()
        for info in infos:
            name = info.filename
            mode = (info.external_attr >> 16) & 0xFFFF
            if stat.S_ISLNK(mode):
                raise ApiError(422, f"bundle entry {name!r}: links are not allowed", "unsafe_path")
            if stat.S_IFMT(mode) not in (0, stat.S_IFREG, stat.S_IFDIR):
                raise ApiError(422, f"bundle entry {name!r}: not a regular file", "unsafe_path")
            if info.flag_bits & 0x1:
                raise ApiError(
                    422, f"bundle entry {name!r}: encrypted entries are not supported", "bad_bundle"
                )
            relative = safe_relative(name, "bundle entry")
            key = str(relative).lower()
            if key in seen:
                raise ApiError(422, f"bundle entry {name!r}: appears twice", "bad_bundle")
            seen.add(key)
            target = inside(root, relative)
            try:
                (target if info.is_dir() else target.parent).mkdir(parents=True, exist_ok=True)
            except OSError:  # an earlier entry is a file where this one needs a folder
                raise ApiError(
                    422, f"bundle entry {name!r}: a file of the bundle is in its way", "bad_bundle"
                ) from None
            if info.is_dir():
                continue
            if info.file_size > CHUNK and info.file_size > settings.max_compression_ratio * max(
                info.compress_size, 1
            ):
                ratio = info.file_size / max(info.compress_size, 1)
                raise ApiError(
                    413,
                    f"bundle entry {name!r} is compressed {ratio:.0f} times (more than "
                    f"{settings.max_compression_ratio:g}): refused as a zip bomb",
                    "zip_bomb",
                )
            written = 0
            try:
                with bundle.open(info) as src, open(target, "xb") as dst:
                    while chunk := src.read(CHUNK):
                        written += len(chunk)
                        total += len(chunk)
                        if written > info.file_size or total > settings.max_unpacked_bytes:
                            raise ApiError(
                                413,
                                f"bundle entry {name!r} unpacks to more than it declares",
                                "zip_bomb",
                            )
                        dst.write(chunk)
            except FileExistsError:
                raise ApiError(422, f"bundle entry {name!r}: appears twice", "bad_bundle") from None
            except (
                zipfile.BadZipFile,
                OSError,
                EOFError,
                NotImplementedError,
                RuntimeError,
            ) as exc:
                raise ApiError(
                    422, f"bundle entry {name!r}: cannot be unpacked ({exc})", "bad_bundle"
                ) from None
            names.append(str(relative))
    if not names:
        raise ApiError(422, "the bundle contains no files", "bad_bundle")
    return names


def find_entry(root: Path, names: list[str]) -> PurePosixPath:
    """The scene file of a bundle: ``scene.json`` at its top, else its only ``.json`` file,
    else its only mesh file."""
    if "scene.json" in names:
        return PurePosixPath("scene.json")
    jsons = [n for n in names if n.lower().endswith(".json")]
    if len(jsons) == 1:
        return PurePosixPath(jsons[0])
    if len(jsons) > 1:
        raise ApiError(
            422, "the bundle has several .json files and no scene.json at its top", "bad_bundle"
        )
    meshes = [n for n in names if PurePosixPath(n).suffix.lower() in MESH_SUFFIXES]
    if len(meshes) == 1:
        return PurePosixPath(meshes[0])
    raise ApiError(
        422, "the bundle has no scene.json (and not exactly one mesh file)", "bad_bundle"
    )


# --- Summaries -----------------------------------------------------------------------------


def count_triangles(state: SceneState) -> int:
    return sum(state.meshes[n.mesh].triangles for n in state.geometry_nodes())


def bounds(state: SceneState) -> tuple[list[float], list[float]] | None:
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    for node in state.geometry_nodes():
        m = state.world_transform(node.id)
        mesh = state.meshes[node.mesh]
        # the box of the mesh's vertices, transformed (exact for the 8 corners' hull)
        vmin, vmax = mesh.vertices.min(axis=0), mesh.vertices.max(axis=0)
        corners = np.array(
            [
                [x, y, z]
                for x in (vmin[0], vmax[0])
                for y in (vmin[1], vmax[1])
                for z in (vmin[2], vmax[2])
            ]
        )
        world = portable.transform_points(corners, m)
        lo = np.minimum(lo, world.min(axis=0))
        hi = np.maximum(hi, world.max(axis=0))
    if not np.isfinite(lo).all():
        return None
    return [float(v) for v in lo], [float(v) for v in hi]


def effects(compiled, render) -> dict:
    """The effect plan the tracers render the scene with:
    ``tracer.integrators.effects.effect_plan`` of the compiled scene under its render settings
    (the same function, so the same answer)."""
    from tracer.integrators.effects import effect_plan
    from tracer.integrators.kernel_choice import plan_report

    return plan_report(effect_plan(compiled, render), render)


def summary(state: SceneState, compiled=None) -> dict:
    """What GET shows of a scene. Needs the compiled scene (its effect plan): compiled here
    unless given, about a second per million triangles, so on a worker thread (numba releases
    the GIL); what the renderer refuses raises SceneError here."""
    if compiled is None:
        from tracer.compiled.scene import compile_scene

        compiled = compile_scene(state)
    box = bounds(state)
    animation = state.animation
    return {
        "triangles": count_triangles(state),
        "nodes": len(state.nodes),
        "meshes": len(state.meshes),
        "materials": sorted(state.materials),
        "bounds": None if box is None else {"min": box[0], "max": box[1]},
        "camera": state.camera.model_dump(),
        "render": state.render.model_dump(),
        "sky": list(mean_sky_radiance(state.sky)),
        "animation": None
        if animation is None
        else {
            "frames": animation.frames,
            "fps": animation.fps,
            "animated_nodes": len(animation.nodes),
            "camera": bool(animation.camera),
        },
        "effects": effects(compiled, state.render),
        "node_list": [
            {
                "id": n.id,
                "name": n.name,
                "kind": n.kind,
                "mesh": n.mesh,
                "material": n.material,
                "parent": n.parent,
            }
            for n in list(state.nodes.values())[:1000]
        ],
    }


# --- The repository --------------------------------------------------------------------------


@dataclass
class Upload:
    """An upload in progress: its staging directory, and the scene it became once kept."""

    staged: Path
    scene_id: str | None = None


class SceneRepository:
    """Scenes on disk and in memory. Methods that read or write files are blocking: call them
    from a worker thread, never from the event loop."""

    def __init__(self, settings: Settings, store: Store) -> None:
        self.settings = settings
        self.store = store
        self.root = settings.data_dir / "scenes"
        self.tmp = settings.data_dir / "tmp"
        self.root.mkdir(parents=True, exist_ok=True)
        shutil.rmtree(self.tmp, ignore_errors=True)
        self.tmp.mkdir(parents=True, exist_ok=True)
        self._entries: dict[str, SceneEntry] = {}
        self._lock = threading.Lock()
        self._compiled: collections.OrderedDict[str, tuple[int, object]] = collections.OrderedDict()

    def _triangles_within_limit(self, state: SceneState, subject: str) -> int:
        """``state``'s triangles; ApiError 422 over ``max_triangles``."""
        triangles = count_triangles(state)
        if triangles > self.settings.max_triangles:
            raise ApiError(
                422,
                f"{subject} {triangles} triangles, more than the limit of "
                f"{self.settings.max_triangles}",
                "too_many_triangles",
            )
        return triangles

    def _compile(self, scene_id: str, state: SceneState) -> dict:
        """``state``'s summary, compiled from the kept compiled form of the scene's previous
        version where there is one (SceneError if the renderer refuses it); keeps the result."""
        from tracer.compiled.scene import compile_scene

        with self._lock:
            kept = self._compiled.get(scene_id)
        previous = kept[1] if kept is not None and kept[0] == state.version - 1 else None
        compiled = compile_scene(state, previous)
        described = summary(state, compiled)
        with self._lock:
            self._compiled[scene_id] = (state.version, compiled)
            self._compiled.move_to_end(scene_id)
            while len(self._compiled) > KEEP_COMPILED:
                self._compiled.popitem(last=False)
        return described

    def staging(self) -> "Upload":
        """A fresh upload in progress, with its own staging directory."""
        path = self.tmp / new_id("u")
        path.mkdir()
        return Upload(path)

    def abandon(self, upload: "Upload") -> None:
        """Undo an upload whose request failed or gave up (a timeout may come after the scene
        was kept): remove its scene, if it became one, and its staging directory."""
        if upload.scene_id is not None and self.store.scene(upload.scene_id) is not None:
            self.delete(upload.scene_id)
        shutil.rmtree(upload.staged, ignore_errors=True)

    def client_error(self, error: ApiError | SceneError, upload: "Upload") -> ApiError:
        """``error`` as the client may see it: paths in the upload named relative to it, no
        other path of the data directory (``api.upload_paths.client_message``)."""
        files = upload.staged / "files"
        if isinstance(error, ApiError):
            message = client_message(error.message, self.settings.data_dir, files)
            return ApiError(error.status, message, error.code, error.headers)
        first = str(error).partition("\n")[0] or "invalid scene"
        return ApiError(422, client_message(first, self.settings.data_dir, files), "invalid_scene")

    def create(self, upload: "Upload", entry: PurePosixPath, name: str, source: str) -> SceneEntry:
        """Load the scene ``entry`` names inside the upload's ``files``, compile it once (so a
        scene the renderer would refuse is refused now, before anything is kept), and keep it
        under a new id."""
        staged = upload.staged
        files = staged / "files"
        scene_path = inside(files, entry)
        if not scene_path.is_file():
            raise ApiError(422, f"{entry}: no such file in the upload", "missing_file")
        check_references(files)
        state = load_scene(scene_path)  # SceneError -> 422
        warnings = load_warnings(scene_path)
        triangles = self._triangles_within_limit(state, "the scene has")
        state = dataclasses.replace(state, version=0)
        scene_id = new_id("s")
        described = self._compile(scene_id, state)  # what the renderer refuses fails here (422)
        directory = self.root / scene_id
        (staged / "commits").mkdir()
        write_atomic(staged / "state.tls", encode_state(state))
        staged.rename(directory)
        self.store.add_scene(scene_id, name, source, str(entry), triangles)
        upload.scene_id = scene_id
        graph = SceneGraph(state, key=scene_id)
        entry_obj = SceneEntry(scene_id, name, source, directory, graph, warnings=warnings)
        entry_obj.summary_cache[state.version] = described
        with self._lock:
            self._entries[scene_id] = entry_obj
        return entry_obj

    def get(self, scene_id: str) -> SceneEntry:
        """The scene (loaded from its state and commits the first time); ApiError 404."""
        with self._lock:
            entry = self._entries.get(scene_id)
        if entry is not None:
            return entry
        record = self.store.scene(scene_id) if _plausible_id(scene_id) else None
        if record is None:
            raise ApiError(404, f"no scene {scene_id!r}", "not_found")
        directory = self.root / scene_id
        try:
            state = decode_state((directory / "state.tls").read_bytes())
            for path in sorted((directory / "commits").glob("*.tlc"), key=lambda p: int(p.stem)):
                commit = decode_commit(path.read_bytes())
                if commit.version <= state.version:
                    continue
                from tracer.scene.ops import apply_commit

                state = apply_commit(state, commit)
        except (OSError, SceneError, ValueError) as exc:
            reason = client_message(str(exc), self.settings.data_dir)
            raise ApiError(
                500, f"scene {scene_id} cannot be restored: {reason}", "corrupt_scene"
            ) from None
        graph = SceneGraph(state, key=scene_id)
        warnings = _upload_warnings(directory / "files", record.get("entry"))
        entry = SceneEntry(
            scene_id, record["name"], record["source"], directory, graph, warnings=warnings
        )
        with self._lock:
            return self._entries.setdefault(scene_id, entry)

    def list(self) -> list[dict]:
        return self.store.scenes()

    def commit(self, entry: SceneEntry, ops: list) -> int:
        """Apply ``ops`` as one commit, all or nothing, and persist it; returns the new version.

        The state the commit makes is checked as strictly as an upload before it becomes the
        scene's version: the triangle limit, then compiled (its summary, kept for the new
        version), so a state the renderer would refuse (every triangle of a mesh of zero area,
        an object beyond float32's range) is refused here with 422 and the scene stays as it
        was. Blocking (compiling takes about a second per million triangles): call it from a
        worker thread."""
        if len(ops) > self.settings.max_ops:
            raise ApiError(
                422, f"a commit may hold at most {self.settings.max_ops} operations", "too_many_ops"
            )
        from tracer.scene.ops import apply_commit, parse_ops

        parsed = parse_ops(ops)  # SceneError -> 422
        with entry.lock:
            state = entry.graph.state
            candidate = apply_commit(state, Commit(state.version + 1, parsed))  # SceneError -> 422
            triangles = self._triangles_within_limit(
                candidate, "after this commit the scene would have"
            )
            described = self._compile(entry.id, candidate)  # what the renderer refuses: 422
            commit = entry.graph.commit(parsed)  # the same ops on the same state: it applies
            version = commit.version
            write_atomic(
                entry.directory / "commits" / f"{version}.tlc",
                encode_commit(Commit(version, commit.ops)),
            )
            entry.commits_since_compaction += 1
            if entry.commits_since_compaction >= COMPACT_EVERY:
                self._compact(entry)
            self.store.set_scene_version(entry.id, version, triangles)
            entry.summary_cache.clear()
            entry.summary_cache[version] = described
        return version

    def _compact(self, entry: SceneEntry) -> None:
        state = entry.graph.state
        write_atomic(entry.directory / "state.tls", encode_state(state))
        for path in (entry.directory / "commits").glob("*.tlc"):
            if int(path.stem) <= state.version:
                path.unlink(missing_ok=True)
        entry.commits_since_compaction = 0

    def summary(self, entry: SceneEntry) -> dict:
        with entry.lock:
            state = entry.graph.state
        cached = entry.summary_cache.get(state.version)
        if cached is None:
            cached = self._compile(entry.id, state)
            entry.summary_cache.clear()
            entry.summary_cache[state.version] = cached
        return {**cached, "version": state.version, "warnings": entry.warnings}

    def delete(self, scene_id: str) -> None:
        if not _plausible_id(scene_id) or self.store.scene(scene_id) is None:
            raise ApiError(404, f"no scene {scene_id!r}", "not_found")
        with self._lock:
            self._entries.pop(scene_id, None)
            self._compiled.pop(scene_id, None)
        self.store.delete_scene(scene_id)
        target = self.root / scene_id
        if target.is_dir():
            trash = self.tmp / f"deleted-{scene_id}"
            target.rename(trash)
            shutil.rmtree(trash, ignore_errors=True)


def _upload_warnings(files: Path, entry: str | None) -> list[str]:
    """``load_warnings`` of a kept upload's scene file (none if it cannot be read again)."""
    try:
        return load_warnings(inside(files, PurePosixPath(entry))) if entry else []
    except (OSError, ValueError, SceneError, ApiError):
        return []


def _plausible_id(ident: str) -> bool:
    return bool(re.fullmatch(r"[a-z][0-9a-f]{12}", ident))

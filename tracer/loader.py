"""Read a scene from disk into :class:`SceneData`: world-space triangle meshes plus settings.

Accepted inputs: a ``tilerender/1`` JSON scene, or a single mesh file (glTF, GLB, OBJ, PLY, STL),
which becomes a scene with a camera framing its bounds and, if nothing in it emits, a default
area light. All mesh I/O goes through trimesh. Every failure raises :class:`SceneError` with a
one-line message; nothing is half-loaded.
"""

import json
import logging
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pydantic
import trimesh

from tracer import scene_format as fmt
from tracer.errors import SceneError
from tracer.shapes import rectangle, shape_mesh

MESH_SUFFIXES = {".obj", ".ply", ".stl", ".gltf", ".glb"}
MAX_SCENE_FILE_BYTES = 16 * 1024 * 1024
DEFAULT_LIGHT_RADIANCE = 12.0
"""Radiance of the default light: about unit irradiance on the scene from a quad of side r at 2r."""


@dataclass
class MeshData:
    """One object in world space: ``vertices`` float64 (V, 3), ``faces`` int64 (F, 3)."""

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    material: int


@dataclass
class SceneData:
    """A loaded scene, ready to compile: materials by index, meshes, camera, render settings."""

    camera: fmt.Camera
    render: fmt.RenderSettings
    material_names: list[str]
    materials: list[fmt.DiffuseMaterial]
    meshes: list[MeshData]
    source: str = ""
    notes: list[str] = field(default_factory=list)


def format_validation_error(error: pydantic.ValidationError) -> str:
    """One line naming the first problem (and how many more there are)."""
    errors = error.errors()
    first = errors[0]
    parts = [str(p) for p in first["loc"] if not str(p).startswith(("tagged-union[", "function-"))]
    where = ".".join(parts) or "scene"
    message = first["msg"]
    if first["type"] == "extra_forbidden":
        message = "unknown key"
    more = f" (and {len(errors) - 1} more problems)" if len(errors) > 1 else ""
    return f"{where}: {message}{more}"


def resolve_reference(scene_dir: Path, reference: str) -> Path:
    """The file ``reference`` names, which must lie inside ``scene_dir``."""
    ref = Path(reference)
    if not ref.parts:
        raise SceneError(f"{reference!r}: not a file name")
    if ref.is_absolute() or reference.startswith(("/", "\\")) or ":" in ref.parts[0]:
        raise SceneError(f"{reference}: file references must be relative to the scene file")
    base = scene_dir.resolve()
    target = (base / ref).resolve()
    if not target.is_relative_to(base):
        raise SceneError(f"{reference}: file references may not leave the scene's directory")
    if not target.is_file():
        raise SceneError(f"{reference}: no such file next to the scene")
    return target


def _validated_mesh(name: str, vertices, faces) -> tuple[np.ndarray, np.ndarray]:
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces)
    if vertices.ndim != 2 or vertices.shape[1] != 3 or faces.ndim != 2 or faces.shape[1] != 3:
        raise SceneError(f"{name}: not a triangle mesh")
    if faces.shape[0] == 0:
        raise SceneError(f"{name}: the mesh has no triangles")
    if not np.isfinite(vertices).all():
        raise SceneError(f"{name}: the mesh has NaN or infinite vertex coordinates")
    if faces.min() < 0 or faces.max() >= vertices.shape[0]:
        raise SceneError(f"{name}: a face refers to a vertex that does not exist")
    return vertices, faces.astype(np.int64)


def _load_trimesh(path: Path):
    logging.getLogger("trimesh").setLevel(logging.ERROR)
    try:
        return trimesh.load(str(path), process=False)
    except Exception as exc:  # trimesh raises many kinds; all mean "cannot read this file"
        raise SceneError(f"{path.name}: cannot read mesh file ({exc})") from None


def load_mesh_file(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """All triangles of a mesh file in its own coordinates (glTF node transforms applied)."""
    loaded = _load_trimesh(path)
    if isinstance(loaded, trimesh.Scene):
        if not loaded.geometry:
            raise SceneError(f"{path.name}: the file contains no meshes")
        loaded = loaded.to_geometry()
    if not isinstance(loaded, trimesh.Trimesh):
        raise SceneError(f"{path.name}: the file holds no triangles (points or lines only?)")
    return _validated_mesh(path.name, loaded.vertices, loaded.faces)


def transform_mesh(vertices: np.ndarray, faces: np.ndarray, matrix: np.ndarray):
    """Apply an affine 4x4 matrix; a mirroring transform reverses winding to keep front faces."""
    with np.errstate(all="ignore"):  # overflow is reported below, as an error
        world = vertices @ matrix[:3, :3].T + matrix[:3, 3]
        mirrored = np.linalg.det(matrix[:3, :3]) < 0.0
    if not np.isfinite(world).all():
        raise SceneError("a transform moves vertices to infinity")
    if mirrored:
        faces = faces[:, ::-1]
    return world, faces


def load_scene(path: str | Path) -> SceneData:
    """Load a JSON scene or a single mesh file."""
    path = Path(path)
    if not path.exists():
        raise SceneError(f"{path}: no such file")
    if not path.is_file():
        raise SceneError(f"{path}: not a file")
    suffix = path.suffix.lower()
    if suffix in MESH_SUFFIXES:
        return scene_from_mesh_file(path)
    if suffix != ".json":
        known = ", ".join(sorted(MESH_SUFFIXES | {".json"}))
        raise SceneError(f"{path}: unknown scene type {suffix or '(none)'!r} (use one of {known})")
    if path.stat().st_size > MAX_SCENE_FILE_BYTES:
        raise SceneError(f"{path}: scene file larger than {MAX_SCENE_FILE_BYTES} bytes")
    try:
        raw = json.loads(
            path.read_text(encoding="utf-8"),
            parse_constant=_reject_constant,
            object_pairs_hook=_reject_duplicate_keys,
        )
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise SceneError(f"{path}: not valid JSON ({exc})") from None
    except RecursionError:
        raise SceneError(f"{path}: JSON nested too deeply") from None
    except ValueError as exc:
        raise SceneError(f"{path}: {exc}") from None
    try:
        scene = fmt.SceneFile.model_validate(raw)
    except pydantic.ValidationError as exc:
        raise SceneError(f"{path}: {format_validation_error(exc)}") from None
    return scene_from_file_model(scene, path.parent, source=str(path))


def _reject_constant(name: str):
    raise ValueError(f"non-finite number {name} is not allowed")


def _reject_duplicate_keys(pairs: list[tuple[str, object]]) -> dict:
    result = {}
    for key, value in pairs:
        if key in result:
            raise ValueError(f"duplicate key {key!r}")
        result[key] = value
    return result


def scene_from_file_model(scene: fmt.SceneFile, scene_dir: Path, source: str = "") -> SceneData:
    """Resolve a validated scene model's meshes (relative to ``scene_dir``) into world space."""
    names = list(scene.materials)
    index = {name: i for i, name in enumerate(names)}
    meshes = []
    for i, obj in enumerate(scene.objects):
        label = obj.name or f"objects[{i}]"
        if isinstance(obj.shape, fmt.MeshFile):
            vertices, faces = load_mesh_file(resolve_reference(scene_dir, obj.shape.path))
        else:
            vertices, faces = shape_mesh(obj.shape)
        try:
            vertices, faces = transform_mesh(vertices, faces, obj.transform.to_matrix())
        except SceneError as exc:
            raise SceneError(f"{label}: {exc}") from None
        meshes.append(MeshData(label, vertices, faces, index[obj.material]))
    return SceneData(
        camera=scene.camera,
        render=scene.render,
        material_names=names,
        materials=[scene.materials[n] for n in names],
        meshes=meshes,
        source=source,
    )


def _gltf_material(material) -> fmt.DiffuseMaterial:
    """Map a trimesh material (glTF PBR or OBJ/MTL) onto a diffuse material."""
    base = np.ones(3)
    emission = np.zeros(3)
    two_sided = True
    if isinstance(material, trimesh.visual.material.PBRMaterial):
        if material.baseColorFactor is not None:
            base = np.asarray(material.baseColorFactor[:3], dtype=np.float64) / 255.0
        if material.emissiveFactor is not None:
            emission = np.asarray(material.emissiveFactor[:3], dtype=np.float64)
        two_sided = bool(material.doubleSided)
    elif isinstance(material, trimesh.visual.material.SimpleMaterial):
        base = np.asarray(material.diffuse[:3], dtype=np.float64) / 255.0
    return fmt.DiffuseMaterial(
        reflectance=tuple(np.clip(base, 0.0, 1.0)),
        emission=tuple(np.maximum(emission, 0.0)),
        two_sided=two_sided,
    )


def scene_from_mesh_file(path: Path) -> SceneData:
    """A scene made of one mesh file: its own materials, a framing camera, a default light."""
    loaded = _load_trimesh(path)
    materials: list[fmt.DiffuseMaterial] = []
    meshes: list[MeshData] = []
    if isinstance(loaded, trimesh.Trimesh):
        parts = [(path.stem, np.eye(4), loaded)]
    elif isinstance(loaded, trimesh.Scene):
        parts = []
        for node in loaded.graph.nodes_geometry:
            matrix, geometry_name = loaded.graph[node]
            geometry = loaded.geometry[geometry_name]
            if isinstance(geometry, trimesh.Trimesh):
                parts.append((str(node), np.asarray(matrix, dtype=np.float64), geometry))
    else:
        parts = []
    if not parts:
        raise SceneError(f"{path.name}: the file contains no triangle meshes")
    for name, matrix, geometry in parts:
        vertices, faces = _validated_mesh(f"{path.name}:{name}", geometry.vertices, geometry.faces)
        vertices, faces = transform_mesh(vertices, faces, matrix)
        materials.append(_gltf_material(getattr(geometry.visual, "material", None)))
        meshes.append(MeshData(name, vertices, faces, len(materials) - 1))

    lo = np.min([m.vertices.min(axis=0) for m in meshes], axis=0)
    hi = np.max([m.vertices.max(axis=0) for m in meshes], axis=0)
    camera = framing_camera(lo, hi)
    names = [f"{path.stem}-{i}" for i in range(len(materials))]
    data = SceneData(camera, fmt.RenderSettings(), names, materials, meshes, source=str(path))
    if not any(max(m.emission) > 0.0 for m in materials):
        add_default_light(data, lo, hi)
    return data


def framing_camera(lo: np.ndarray, hi: np.ndarray, vfov_deg: float = 40.0) -> fmt.Camera:
    """A camera in front of (+z) and a little above the bounds, seeing all of them."""
    center = 0.5 * (lo + hi)
    radius = max(0.5 * float(np.linalg.norm(hi - lo)), 1e-30)
    direction = np.array([0.0, 0.35, 1.0]) / np.linalg.norm([0.0, 0.35, 1.0])
    distance = 1.1 * radius / math.sin(math.radians(vfov_deg) * 0.5)
    return fmt.Camera(
        position=tuple(center + distance * direction),
        look_at=tuple(center),
        up=(0.0, 1.0, 0.0),
        vfov_deg=vfov_deg,
    )


def add_default_light(data: SceneData, lo: np.ndarray, hi: np.ndarray) -> None:
    """Add a square area light above the camera side of the bounds, facing their centre."""
    center = 0.5 * (lo + hi)
    radius = max(0.5 * float(np.linalg.norm(hi - lo)), 1e-30)
    toward = np.array([0.3, 1.0, 0.6]) / np.linalg.norm([0.3, 1.0, 0.6])
    position = center + 2.0 * radius * toward
    normal = -toward  # the rectangle faces +z; rotate +z onto the normal
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(z, normal)
    angle = math.acos(float(np.clip(np.dot(z, normal), -1.0, 1.0)))
    rotation = trimesh.transformations.rotation_matrix(angle, axis)
    vertices, faces = rectangle(radius, radius)
    vertices = vertices @ rotation[:3, :3].T + position
    data.material_names.append("default-light")
    data.materials.append(
        fmt.DiffuseMaterial(
            reflectance=(0.0, 0.0, 0.0),
            emission=(DEFAULT_LIGHT_RADIANCE,) * 3,
            two_sided=False,
        )
    )
    data.meshes.append(MeshData("default-light", vertices, faces, len(data.materials) - 1))
    data.notes.append("no emitter in the file: added a default area light")

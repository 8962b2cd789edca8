"""Read a scene from disk into a :class:`tracer.scene.model.SceneState`.

Accepted inputs: a ``tilerender/1`` JSON scene, or a single mesh file (glTF, GLB, OBJ, PLY, STL),
which becomes a scene with the file's camera or one framing its bounds, the file's lights and,
if nothing in it emits or lights, a default area light. All mesh I/O goes through trimesh
(``tracer.scene.mesh_files``), images through Pillow (``tracer.shading.textures``). Every failure
raises :class:`SceneError` with a one-line message; nothing is half-loaded.
"""

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pydantic
import trimesh

from tracer.errors import SceneError, format_validation_error
from tracer.maths import portable
from tracer.scene import format as fmt
from tracer.scene.animation import (
    camera_at,
    frame_time,
    matrix_to_trs,
    node_transform,
    quaternion_from_euler_xyz,
)
from tracer.scene.checks import check_textures
from tracer.scene.environment import EnvironmentMap, read_environment_image
from tracer.scene.gltf_cameras import bare_file_camera
from tracer.scene.gltf_features import feature_warnings, gltf_json
from tracer.scene.gltf_lights import file_lights
from tracer.scene.gltf_placement import object_camera, object_lights
from tracer.scene.mesh_files import FileModel, load_file_model, load_mesh_file, shading_key
from tracer.scene.model import (
    Animation,
    CameraKey,
    Mesh,
    Node,
    NodeKey,
    SceneState,
    frozen_array,
    make_mesh,
)
from tracer.scene.shapes import rectangle, shape_mesh, shape_normals, shape_uvs
from tracer.shading.textures import alpha_image_name, material_texture, read_texture

IDENTITY = frozen_array(np.eye(4), np.float64)

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
    """A scene given as world-space meshes (a convenient way to build one in code): materials by
    index, meshes, camera, render settings. :meth:`to_state` makes it a scene of static nodes."""

    camera: fmt.Camera
    render: fmt.RenderSettings
    material_names: list[str]
    materials: list[fmt.Material]
    meshes: list[MeshData]
    source: str = ""
    notes: list[str] = field(default_factory=list)
    sky: fmt.Sky = field(default_factory=fmt.ConstantSky)
    lights: list[fmt.Light] = field(default_factory=list)

    def to_state(self) -> SceneState:
        meshes, nodes = {}, {}
        for i, m in enumerate(self.meshes):
            key = f"{i}:{m.name}"
            meshes[key] = make_mesh(m.vertices, m.faces, m.name)
            nodes[i] = Node(
                i, m.name, None, IDENTITY, "static", key, self.material_names[m.material]
            )
        return SceneState(
            version=0,
            meshes=meshes,
            materials=dict(zip(self.material_names, self.materials, strict=True)),
            nodes=nodes,
            camera=self.camera,
            render=self.render,
            sky=self.sky,
            lights=tuple(self.lights),
        )


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


def load_sky(sky: fmt.Sky, scene_dir: Path) -> fmt.Sky | EnvironmentMap:
    """The sky a state holds: an environment sky with its image read (relative to
    ``scene_dir``), any other sky as it is."""
    if not isinstance(sky, fmt.EnvironmentSky):
        return sky
    try:
        path = resolve_reference(scene_dir, sky.file)
    except SceneError as exc:
        raise SceneError(f"sky: {exc}") from None
    return EnvironmentMap(sky, read_environment_image(path, f"sky: {sky.file}"))


def load_scene(path: str | Path) -> SceneState:
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


def load_warnings(path: str | Path) -> list[str]:
    """What loading ``path`` (a scene :func:`load_scene` accepts) ignores or approximates of
    its glTF files, one line per feature and file (``tracer.scene.gltf_features``): about
    materials only for files whose own materials are used, about lights and cameras as the
    scene takes them (a file alone takes both)."""
    path = Path(path)
    files: dict[str, Path] = {}
    taken: dict[str, set[str]] = {}  # reference -> what the scene takes of the file
    if path.suffix.lower() in MESH_SUFFIXES:
        files[path.name] = path
        taken[path.name] = {"materials", "lights", "camera"}
    else:
        scene = fmt.SceneFile.model_validate_json(path.read_text(encoding="utf-8"))
        viewer = getattr(scene.camera, "from_object", None)
        for obj in scene.objects:
            if isinstance(obj.shape, fmt.MeshFile):
                reference = obj.shape.path
                if reference not in files:
                    files[reference] = resolve_reference(path.parent, reference)
                uses = taken.setdefault(reference, set())
                uses |= {"materials"} if obj.material is None else set()
                uses |= {"lights"} if obj.shape.lights else set()
                uses |= {"camera"} if obj.name and obj.name == viewer else set()
    warnings = []
    for reference, file in files.items():
        document = gltf_json(file)
        if document is not None:
            uses = taken[reference]
            found = feature_warnings(
                document, *(k in uses for k in ("materials", "lights", "camera"))
            )
            warnings += [f"{reference}: {w}" for w in found]
    return warnings


def _reject_constant(name: str):
    raise ValueError(f"non-finite number {name} is not allowed")


def _reject_duplicate_keys(pairs: list[tuple[str, object]]) -> dict:
    result = {}
    for key, value in pairs:
        if key in result:
            raise ValueError(f"duplicate key {key!r}")
        result[key] = value
    return result


def scene_from_file_model(scene: fmt.SceneFile, scene_dir: Path, source: str = "") -> SceneState:
    """The state a validated scene model describes, meshes resolved relative to ``scene_dir``.

    Objects become nodes (ids in file order, parents by name); objects with the same shape
    share one mesh (instancing). An object without a material (a mesh file with its own) is a
    grouping node whose children, with ids after every object's, are the file's mesh nodes
    with the file's materials (``tracer.scene.mesh_files``). Textures are read relative to
    ``scene_dir``. With an ``animation`` section the state is posed at frame 0: an animated
    object's transform, and the camera if it is animated, are the animation's values at time 0
    (see :func:`animation_from_file`).
    """
    if isinstance(scene.camera, fmt.FileCamera):
        camera = object_camera(scene, scene_dir, resolve_reference)
        scene = scene.model_copy(update={"camera": camera})
    names = {obj.name: i for i, obj in enumerate(scene.objects) if obj.name}
    animation = animation_from_file(scene)
    camera = scene.camera
    start = 0.0
    if animation is not None:
        start = frame_time(animation, 0)
        if animation.camera:
            camera = camera_at(animation.camera, start, scene.camera)
    meshes: dict[str, Mesh] = {}
    nodes: dict[int, Node] = {}
    materials: dict[str, fmt.Material] = dict(scene.materials)
    textures = material_textures(scene.materials, scene_dir)
    file_models: dict[str, FileModel] = {}
    file_materials: dict[str, str] = {}
    children: list[tuple[int, FileModel]] = []
    for i, obj in enumerate(scene.objects):
        label = obj.name or f"objects[{i}]"
        if obj.material is None:
            key = None
            reference = obj.shape.path
            loaded_as = reference + shading_key(obj.shape)
            if loaded_as not in file_models:
                model = load_file_model(
                    resolve_reference(scene_dir, reference),
                    reference,
                    f"file:{loaded_as}#",
                    obj.shape,
                )
                for name in model.materials:
                    if name in materials and file_materials.get(name) != reference:
                        raise SceneError(
                            f"{label}: the file's material {name!r} has the name of a material "
                            "of the scene; rename that one"
                        )
                    file_materials[name] = reference
                file_models[loaded_as] = model
                meshes.update(model.meshes)
                materials.update(model.materials)
                textures.update(model.textures)
            children.append((i, file_models[loaded_as]))
        elif isinstance(obj.shape, fmt.MeshFile):
            key = f"file:{obj.shape.path}{shading_key(obj.shape)}"
            if key not in meshes:
                path = resolve_reference(scene_dir, obj.shape.path)
                meshes[key] = load_mesh_file(path, obj.shape)
        else:
            key = f"shape:{obj.shape.model_dump_json()}"
            if key not in meshes:
                meshes[key] = make_mesh(
                    *shape_mesh(obj.shape), label, shape_uvs(obj.shape), shape_normals(obj.shape)
                )
        parent = None
        if obj.parent is not None:
            if obj.parent not in names:
                raise SceneError(f"{label}: parent {obj.parent!r} is not an object of the scene")
            parent = names[obj.parent]
            if parent >= i:
                raise SceneError(f"{label}: a parent must come before its children")
        if animation is not None and i in animation.nodes:
            matrix = node_transform(animation.nodes[i], start)
        else:
            matrix = obj.transform.to_matrix()
        transform = frozen_array(matrix, np.float64)
        nodes[i] = Node(i, obj.name or label, parent, transform, obj.kind, key, obj.material)
    next_id = len(scene.objects)
    for parent, model in children:
        kind = scene.objects[parent].kind
        for name, matrix, mesh_key, material_key in model.parts:
            label = f"{nodes[parent].name}/{name}"
            nodes[next_id] = Node(next_id, label, parent, matrix, kind, mesh_key, material_key)
            next_id += 1
    state = SceneState(
        version=0,
        meshes=meshes,
        materials=materials,
        nodes=nodes,
        camera=camera,
        render=scene.render,
        sky=load_sky(scene.sky, scene_dir),
        animation=animation,
        lights=(*scene.lights, *object_lights(scene, scene_dir, resolve_reference)),
        textures=textures,
    )
    check_textures(state)
    return state


def material_textures(materials: dict[str, fmt.Material], scene_dir: Path) -> dict:
    """The images the scene's materials name, read relative to ``scene_dir`` (by file name as
    written), as ``tracer.shading.textures`` pixels."""
    textures: dict = {}
    for name, material in materials.items():
        alpha = getattr(material, "alpha", None)
        named = (("texture", material_texture(material), False),
                 ("normal_map", getattr(material, "normal_map", None), False),
                 ("alpha.texture", None if alpha is None else alpha.texture, True))  # fmt: skip
        for what, texture, alpha_channel in named:
            if texture is None:
                continue
            key = alpha_image_name(texture.file) if alpha_channel else texture.file
            if key not in textures:
                path = resolve_reference(scene_dir, texture.file)
                label = f"materials.{name}.{what}: {texture.file}"
                textures[key] = read_texture(path, label, alpha=alpha_channel)
    return textures


def animation_from_file(scene: fmt.SceneFile) -> Animation | None:
    """The scene's ``animation`` section with objects resolved to node ids (file order) and every
    key completed: a field a key leaves out is the object's own transform component (translate,
    rotation, scale; a ``matrix`` transform is split into them) or the scene camera's value.

    Raises SceneError for an object that does not exist, is named more than once or is static;
    for a matrix that cannot be split when a key needs its parts; for a scale that changes sign
    between keys (it would pass through zero); and for a camera that is invalid at a key or at
    any frame between keys.
    """
    section = scene.animation
    if section is None:
        return None
    ids: dict[str, list[int]] = {}
    for i, obj in enumerate(scene.objects):
        if obj.name:
            ids.setdefault(obj.name, []).append(i)
    tracks: dict[int, tuple[NodeKey, ...]] = {}
    for name, keys in section.objects.items():
        found = ids.get(name, [])
        if not found:
            known = sorted(ids)
            listed = ", ".join(known[:10]) + (", ..." if len(known) > 10 else "")
            raise SceneError(
                f"animation: no object is named {name!r} (named objects: {listed or 'none'})"
            )
        if len(found) > 1:
            raise SceneError(
                f"animation: {len(found)} objects are named {name!r}; an animated object needs "
                "a name of its own"
            )
        obj = scene.objects[found[0]]
        if obj.kind == "static":
            raise SceneError(
                f"animation: object {name!r} is static, and static objects cannot move; "
                'give it "kind": "rigid"'
            )
        tracks[found[0]] = _object_track(f"animation.objects.{name}", obj.transform, keys)
    camera = () if section.camera is None else _camera_track(section.camera, scene.camera)
    animation = Animation(
        fps=float(section.fps),
        frames=section.frames,
        nodes=dict(sorted(tracks.items())),
        camera=camera,
    )
    _check_camera_between_keys(animation, scene.camera)
    return animation


def _transform_parts(where: str, transform: fmt.Transform):
    """``(translate, rotation quaternion, scale)`` of a file transform."""
    if transform.matrix is None:
        scale = np.broadcast_to(np.asarray(transform.scale, dtype=np.float64), (3,))
        return (
            tuple(transform.translate),
            quaternion_from_euler_xyz(transform.rotate),
            tuple(float(c) for c in scale),
        )
    try:
        return matrix_to_trs(transform.matrix)
    except SceneError:
        raise SceneError(
            f"{where}: a key leaves out translate, rotation or scale, but the object's transform "
            "matrix shears and cannot be split into them; give all three in every key"
        ) from None


def _object_track(
    where: str, transform: fmt.Transform, keys: list[fmt.ObjectKeyframe]
) -> tuple[NodeKey, ...]:
    parts = None
    result = []
    for key in keys:
        no_rotation = key.rotate is None and key.rotation is None
        if parts is None and (key.translate is None or key.scale is None or no_rotation):
            parts = _transform_parts(where, transform)
        translate = parts[0] if key.translate is None else key.translate
        if key.rotation is not None:
            rotation = key.rotation
        elif key.rotate is not None:
            rotation = quaternion_from_euler_xyz(key.rotate)
        else:
            rotation = parts[1]
        scale = parts[2] if key.scale is None else np.broadcast_to(key.scale, (3,))
        result.append(
            NodeKey(
                float(key.time),
                tuple(float(c) for c in translate),
                tuple(float(c) for c in rotation),
                tuple(float(c) for c in scale),
            )
        )
    scales = np.array([key.scale for key in result])
    flips = np.sign(scales[1:]) != np.sign(scales[:-1])
    if flips.any():
        i, axis = np.argwhere(flips)[0]
        raise SceneError(
            f"{where}: the {'xyz'[axis]} scale changes sign between keys {i} and {i + 1}, so "
            "between them it would pass through zero (a singular transform)"
        )
    with np.errstate(all="ignore"):
        smallest = np.prod(np.abs(scales).min(axis=0))
        largest = np.prod(np.abs(scales).max(axis=0))
    if not (smallest > 0.0 and np.isfinite(largest)):
        raise SceneError(f"{where}: scales so small or so large make the transform singular")
    return tuple(result)


def _camera_track(keys: list[fmt.CameraKeyframe], base: fmt.Camera) -> tuple[CameraKey, ...]:
    result = []
    for i, key in enumerate(keys):
        values = {
            name: getattr(base, name) if getattr(key, name) is None else getattr(key, name)
            for name in ("position", "look_at", "up", "vfov_deg")
        }
        try:
            fmt.Camera(**values, width=base.width, height=base.height)
        except pydantic.ValidationError as exc:
            problem = exc.errors()[0]["msg"].removeprefix("Value error, ")
            raise SceneError(f"animation.camera.{i} (time {key.time}): {problem}") from None
        result.append(
            CameraKey(
                float(key.time),
                tuple(float(c) for c in values["position"]),
                tuple(float(c) for c in values["look_at"]),
                tuple(float(c) for c in values["up"]),
                float(values["vfov_deg"]),
            )
        )
    return tuple(result)


def _check_camera_between_keys(animation: Animation, base: fmt.Camera) -> None:
    """Every frame between two camera keys gives a valid camera (the keys themselves are valid,
    but interpolating them can make, say, position meet look_at)."""
    keys = animation.camera
    if len(keys) < 2:
        return
    key_times = {key.time for key in keys}
    for frame in range(animation.frames):
        time = frame_time(animation, frame)
        if time >= keys[-1].time:
            break
        if time > keys[0].time and time not in key_times:
            try:
                camera_at(keys, time, base)
            except SceneError as exc:
                message = f"animation.camera: frame {frame} is not a valid view ({exc})"
                raise SceneError(message) from None


def scene_from_mesh_file(path: Path) -> SceneState:
    """A scene made of one mesh file: its own materials and textures (``tracer.scene.mesh_files``)
    and a glTF file's lights; its first perspective camera, else a framing one; a default light
    when nothing emits or lights."""
    model = load_file_model(path, path.name, f"{path.name}:")
    document = gltf_json(path)
    lights = () if document is None else tuple(file_lights(document, path.name))
    file_camera = None if document is None else bare_file_camera(document, path.name)
    nodes: dict[int, Node] = {}
    corners = []
    for i, (name, transform, mesh_key, material_key) in enumerate(model.parts):
        nodes[i] = Node(i, name, None, transform, "static", mesh_key, material_key)
        v = portable.transform_points(model.meshes[mesh_key].vertices, transform)
        corners += [v.min(axis=0), v.max(axis=0)]
    lo = np.min(corners, axis=0)
    hi = np.max(corners, axis=0)
    state = SceneState(
        version=0,
        meshes=model.meshes,
        materials=model.materials,
        nodes=nodes,
        camera=file_camera or framing_camera(lo, hi),
        render=fmt.RenderSettings(),
        lights=lights,
        textures=model.textures,
    )
    emits = any(max(getattr(m, "emission", (0.0,))) > 0.0 for m in model.materials.values())
    if not emits and not lights:
        state = with_default_light(state, lo, hi)
    return state


def framing_camera(lo: np.ndarray, hi: np.ndarray, vfov_deg: float = 40.0) -> fmt.Camera:
    """A camera in front of (+z) and a little above the bounds, seeing all of them."""
    center = 0.5 * (lo + hi)
    radius = max(0.5 * portable.norm(hi - lo), 1e-30)
    direction = portable.normalized([0.0, 0.35, 1.0])
    distance = 1.1 * radius / math.sin(math.radians(vfov_deg) * 0.5)
    return fmt.Camera(
        position=tuple(center + distance * direction),
        look_at=tuple(center),
        up=(0.0, 1.0, 0.0),
        vfov_deg=vfov_deg,
    )


DEFAULT_LIGHT = "default-light"


def with_default_light(state: SceneState, lo: np.ndarray, hi: np.ndarray) -> SceneState:
    """The state plus a square area light above the camera side of the bounds, facing their
    centre (a node and a material both named ``default-light``)."""
    center = 0.5 * (lo + hi)
    radius = max(0.5 * portable.norm(hi - lo), 1e-30)
    toward = portable.normalized([0.3, 1.0, 0.6])
    normal = -toward  # the rectangle faces +z; rotate +z onto the normal
    z = np.array([0.0, 0.0, 1.0])
    angle = math.acos(min(max(portable.dot(z, normal), -1.0), 1.0))
    matrix = trimesh.transformations.rotation_matrix(angle, portable.cross(z, normal))
    matrix[:3, 3] = center + 2.0 * radius * toward
    node_id = max(state.nodes) + 1
    light = Node(
        node_id, DEFAULT_LIGHT, None, frozen_array(matrix, np.float64), "static", DEFAULT_LIGHT,
        DEFAULT_LIGHT,
    )  # fmt: skip
    material = fmt.DiffuseMaterial(
        reflectance=(0.0, 0.0, 0.0), emission=(DEFAULT_LIGHT_RADIANCE,) * 3, two_sided=False
    )
    return SceneState(
        version=state.version,
        meshes={
            **state.meshes,
            DEFAULT_LIGHT: make_mesh(*rectangle(radius, radius), DEFAULT_LIGHT),
        },
        materials={**state.materials, DEFAULT_LIGHT: material},
        nodes={**state.nodes, node_id: light},
        camera=state.camera,
        render=state.render,
        sky=state.sky,
        animation=state.animation,
        lights=state.lights,
        textures=state.textures,
    )

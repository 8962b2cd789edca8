"""Compact binary form of commits and snapshots, for sending them to replicas.

Layout (little-endian)::

    magic  b"TLR1"                       4 bytes
    crc32 of everything after this field  uint32
    header length                        uint32
    header                               UTF-8 JSON: the structure, arrays as {"$array": i}
    zero padding to a multiple of 8
    arrays                               raw bytes, one after the other, in header["arrays"] order,
                                         each zero-padded to a multiple of 8 bytes

``header["arrays"]`` lists each array's ``[dtype, shape]`` (``"<f8"``, ``"<i8"``, or ``"|u1"``
for texture images); offsets follow from the shapes. Floats in the header are written with
``repr``, so every round trip is exact: arrays bit for bit, models equal. Decoding checks the
checksum, every length, the header against a schema, and the decoded scene's invariants
(``tracer.scene.checks``), and raises :class:`SceneError` for anything malformed.
"""

import json
import math
import struct
import zlib
from typing import Annotated, Any, Literal

import numpy as np
import pydantic
from pydantic import BaseModel, ConfigDict, Field

from tracer.errors import SceneError, format_validation_error
from tracer.scene import format as fmt
from tracer.scene.checks import check_state
from tracer.scene.environment import EnvironmentMap, check_image
from tracer.scene.model import (
    Animation,
    CameraKey,
    Node,
    NodeKey,
    NodeKind,
    SceneState,
    frozen_array,
    make_mesh,
)
from tracer.scene.ops import Commit, parse_ops

MAGIC = b"TLR1"
_PREFIX = struct.Struct("<4sII")
_DTYPES = {"f": "<f8", "i": "<i8"}
_BYTES = "|u1"
"""uint8 arrays (texture images) keep their type; every other array is stored by kind."""
_KEY_COLUMNS = 11
"""Node keys: time, translate (3), rotation (4), scale (3). Camera keys: time, position (3),
look_at (3), up (3), vfov_deg."""


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, strict=True)


_ArrayIndex = Annotated[int, Field(ge=0)]
_ArraySpec = tuple[
    Literal["<f8", "<i8", "|u1"],
    Annotated[list[Annotated[int, Field(ge=0)]], Field(max_length=3)],
]


class _CommitHeader(_Strict):
    kind: Literal["commit"]
    version: int
    ops: list[dict[str, Any]]
    arrays: list[_ArraySpec]


class _AnimationHeader(_Strict):
    fps: fmt.Finite
    frames: int
    nodes: list[tuple[int, _ArrayIndex]]
    camera: _ArrayIndex | None


class _StateHeader(_Strict):
    kind: Literal["state"]
    version: int
    camera: fmt.Camera
    render: fmt.RenderSettings
    sky: fmt.Sky
    environment: _ArrayIndex | None = None
    """An environment sky's image (H, W, 3)."""
    lights: list[fmt.Light]
    materials: list[tuple[str, fmt.Material]]
    meshes: list[tuple[str, _ArrayIndex, _ArrayIndex]]
    mesh_uvs: list[tuple[str, _ArrayIndex]] = []
    mesh_normals: list[tuple[str, _ArrayIndex]] = []
    textures: list[tuple[str, _ArrayIndex]] = []
    nodes: list[tuple[int, str, int | None, NodeKind, str | None, str | None]]
    transforms: _ArrayIndex
    animation: _AnimationHeader | None
    arrays: list[_ArraySpec]


class _Arrays:
    """Arrays gathered while encoding; each is referred to by its index."""

    def __init__(self) -> None:
        self.items: list[np.ndarray] = []

    def add(self, array: np.ndarray) -> int:
        dtype = _BYTES if array.dtype == np.uint8 else _DTYPES[array.dtype.kind]
        self.items.append(np.ascontiguousarray(array, dtype=dtype))
        return len(self.items) - 1

    def ref(self, array: np.ndarray) -> dict[str, int]:
        return {"$array": self.add(array)}


def encode_commit(commit: Commit) -> bytes:
    """The commit as bytes (see the module docstring for the layout)."""
    arrays = _Arrays()
    ops = []
    for op in commit.ops:
        fields = op.model_dump(exclude_defaults=True, exclude={"op"})
        ops.append({"op": op.op, **_replace_arrays(fields, arrays)})
    header = {"kind": "commit", "version": commit.version, "ops": ops}
    return _pack(header, arrays)


def decode_commit(data: bytes) -> Commit:
    """The commit ``data`` encodes; SceneError if it is malformed, truncated or corrupted."""
    try:
        header, arrays = _unpack(data, _CommitHeader)
        return Commit(header.version, parse_ops(_restore_arrays(header.ops, arrays)))
    except SceneError as error:
        raise SceneError(f"cannot decode commit: {error}") from None


def encode_state(state: SceneState) -> bytes:
    """A snapshot of the whole state as bytes."""
    arrays = _Arrays()
    nodes = list(state.nodes.values())
    transforms = np.stack([n.transform for n in nodes]) if nodes else np.zeros((0, 4, 4))
    sky, environment = state.sky, None
    if isinstance(sky, EnvironmentMap):
        sky, environment = sky.model, arrays.add(sky.image)  # float32 -> float64 exactly
    header = {
        "kind": "state",
        "version": state.version,
        "camera": state.camera.model_dump(),
        "render": state.render.model_dump(),
        "sky": sky.model_dump(),
        "environment": environment,
        "lights": [light.model_dump() for light in state.lights],
        "materials": [[name, m.model_dump()] for name, m in state.materials.items()],
        "meshes": [
            [name, arrays.add(m.vertices), arrays.add(m.faces)] for name, m in state.meshes.items()
        ],
        "mesh_uvs": [
            [name, arrays.add(m.uvs)] for name, m in state.meshes.items() if m.uvs is not None
        ],
        "mesh_normals": [
            [name, arrays.add(m.normals)]
            for name, m in state.meshes.items()
            if m.normals is not None
        ],
        "textures": [[name, arrays.add(pixels)] for name, pixels in state.textures.items()],
        "nodes": [[n.id, n.name, n.parent, n.kind, n.mesh, n.material] for n in nodes],
        "transforms": arrays.add(transforms),
        "animation": _encode_animation(state.animation, arrays),
    }
    return _pack(header, arrays)


def decode_state(data: bytes) -> SceneState:
    """The snapshot ``data`` encodes, checked like any state from outside (SceneError if not)."""
    try:
        header, arrays = _unpack(data, _StateHeader)
        state = _build_state(header, arrays)
        check_state(state)
        return state
    except SceneError as error:
        raise SceneError(f"cannot decode snapshot: {error}") from None


def _encode_animation(animation: Animation | None, arrays: _Arrays) -> dict | None:
    if animation is None:
        return None
    tracks = [
        [node_id, arrays.add(np.array([_node_row(k) for k in keys], dtype=np.float64))]
        for node_id, keys in animation.nodes.items()
    ]
    camera = None
    if animation.camera:
        rows = [_camera_row(k) for k in animation.camera]
        camera = arrays.add(np.array(rows, dtype=np.float64))
    return {"fps": animation.fps, "frames": animation.frames, "nodes": tracks, "camera": camera}


def _node_row(key: NodeKey) -> list[float]:
    return [key.time, *key.translate, *key.rotation, *key.scale]


def _camera_row(key: CameraKey) -> list[float]:
    return [key.time, *key.position, *key.look_at, *key.up, key.vfov_deg]


def _replace_arrays(value, arrays: _Arrays):
    if isinstance(value, np.ndarray):
        return arrays.ref(value)
    if isinstance(value, dict):
        return {k: _replace_arrays(v, arrays) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_replace_arrays(v, arrays) for v in value]
    return value


def _restore_arrays(value, arrays: list[np.ndarray]):
    if isinstance(value, dict):
        if value.keys() == {"$array"}:
            return _array(arrays, value["$array"])
        return {k: _restore_arrays(v, arrays) for k, v in value.items()}
    if isinstance(value, list):
        return [_restore_arrays(v, arrays) for v in value]
    return value


def _array(arrays: list[np.ndarray], index, dtype: str | None = None, shape=None) -> np.ndarray:
    """``arrays[index]``, checked against the expected dtype and shape (None: any size)."""
    if not isinstance(index, int) or isinstance(index, bool) or not 0 <= index < len(arrays):
        raise SceneError(f"array reference {index!r} does not exist")
    array = arrays[index]
    if dtype is not None and array.dtype != np.dtype(dtype):
        raise SceneError(f"array {index} has dtype {array.dtype}, expected {dtype}")
    if shape is not None and (
        array.ndim != len(shape)
        or any(s is not None and a != s for a, s in zip(array.shape, shape, strict=True))
    ):
        raise SceneError(f"array {index} has shape {array.shape}, expected {shape}")
    return array


def _build_state(header: _StateHeader, arrays: list[np.ndarray]) -> SceneState:
    uvs = {}
    for name, index in header.mesh_uvs:
        if name in uvs:
            raise SceneError(f"the UVs of mesh {name!r} appear twice")
        uvs[name] = _array(arrays, index, "<f8", (None, 2))
    normals = {}
    for name, index in header.mesh_normals:
        if name in normals:
            raise SceneError(f"the normals of mesh {name!r} appear twice")
        normals[name] = _array(arrays, index, "<f8", (None, 3))
    meshes = {}
    for name, vertices, faces in header.meshes:
        if name in meshes:
            raise SceneError(f"mesh {name!r} appears twice")
        meshes[name] = make_mesh(
            _array(arrays, vertices, "<f8"),
            _array(arrays, faces, "<i8"),
            f"mesh {name!r}",
            uvs.pop(name, None),
            normals.pop(name, None),
            unit_normals=True,
        )
    if uvs:
        raise SceneError(f"UVs for mesh {next(iter(uvs))!r}, which does not exist")
    if normals:
        raise SceneError(f"normals for mesh {next(iter(normals))!r}, which does not exist")
    textures = {}
    for name, index in header.textures:
        if name in textures:
            raise SceneError(f"texture {name!r} appears twice")
        textures[name] = frozen_array(_array(arrays, index, "|u1", (None, None, 3)), np.uint8)
    materials = dict(header.materials)
    if len(materials) != len(header.materials):
        raise SceneError("a material name appears twice")
    transforms = _array(arrays, header.transforms, "<f8", (len(header.nodes), 4, 4))
    nodes = {}
    for row, transform in zip(header.nodes, transforms, strict=True):
        node = Node(*row[:3], frozen_array(transform, np.float64), *row[3:])
        if node.id in nodes:
            raise SceneError(f"node id {node.id} appears twice")
        nodes[node.id] = node
    return SceneState(
        version=header.version,
        meshes=meshes,
        materials=materials,
        nodes=nodes,
        camera=header.camera,
        render=header.render,
        sky=_decode_sky(header, arrays),
        lights=tuple(header.lights),
        animation=_decode_animation(header.animation, arrays),
        textures=textures,
    )


def _decode_sky(header: _StateHeader, arrays: list[np.ndarray]):
    """The header's sky, an environment sky with its image."""
    if not isinstance(header.sky, fmt.EnvironmentSky):
        if header.environment is not None:
            raise SceneError("an environment image without an environment sky")
        return header.sky
    if header.environment is None:
        raise SceneError("the environment sky has no image")
    image = _array(arrays, header.environment, "<f8", (None, None, 3))
    return EnvironmentMap(header.sky, check_image(image, f"sky: {header.sky.file}"))


def _decode_animation(header: _AnimationHeader | None, arrays) -> Animation | None:
    if header is None:
        return None
    tracks = {}
    for node_id, index in header.nodes:
        if node_id in tracks:
            raise SceneError(f"node {node_id} has two animation tracks")
        rows = _array(arrays, index, "<f8", (None, _KEY_COLUMNS)).tolist()
        tracks[node_id] = tuple(
            NodeKey(r[0], tuple(r[1:4]), tuple(r[4:8]), tuple(r[8:11])) for r in rows
        )
    camera = ()
    if header.camera is not None:
        rows = _array(arrays, header.camera, "<f8", (None, _KEY_COLUMNS)).tolist()
        camera = tuple(
            CameraKey(r[0], tuple(r[1:4]), tuple(r[4:7]), tuple(r[7:10]), r[10]) for r in rows
        )
    return Animation(fps=header.fps, frames=header.frames, nodes=tracks, camera=camera)


def _pack(header: dict, arrays: _Arrays) -> bytes:
    header["arrays"] = [[a.dtype.str, list(a.shape)] for a in arrays.items]
    text = json.dumps(header, separators=(",", ":"), allow_nan=False).encode()
    padding = b"\0" * (-(_PREFIX.size + len(text)) % 8)
    length = struct.pack("<I", len(text))
    parts = [length, text, padding]
    for a in arrays.items:
        parts += [a.data, b"\0" * (-a.nbytes % 8)]
    crc = 0
    for part in parts:
        crc = zlib.crc32(part, crc)
    return b"".join([MAGIC, struct.pack("<I", crc), *parts])


def _unpack(data: bytes, model: type[BaseModel]) -> tuple[Any, list[np.ndarray]]:
    """The validated header and the arrays of ``data``."""
    try:
        view = memoryview(data).cast("B")
    except TypeError:
        raise SceneError(f"expected bytes, not {type(data).__name__}") from None
    if len(view) < _PREFIX.size:
        raise SceneError(f"{len(view)} bytes: too short (truncated?)")
    magic, crc, header_length = _PREFIX.unpack_from(view)
    if magic != MAGIC:
        raise SceneError("not tilerender data (wrong magic bytes)")
    if zlib.crc32(view[8:]) != crc:
        raise SceneError("checksum mismatch (truncated or corrupted data)")
    end = _PREFIX.size + header_length
    if end > len(view):
        raise SceneError("the header runs past the end of the data")
    try:
        header = model.model_validate_json(bytes(view[_PREFIX.size : end]))
    except pydantic.ValidationError as error:
        first = error.errors()[0]
        if first["type"] == "json_invalid":
            raise SceneError(f"the header is not JSON ({first['msg']})") from None
        raise SceneError(f"header: {format_validation_error(error)}") from None
    offset = end + (-end % 8)
    arrays = []
    for dtype, shape in header.arrays:
        count = math.prod(shape)
        size = count * np.dtype(dtype).itemsize
        if offset + size > len(view):
            raise SceneError("an array runs past the end of the data (truncated?)")
        arrays.append(np.frombuffer(view, dtype, count, offset).reshape(shape))
        offset += size + (-size % 8)
    if offset != len(view):
        raise SceneError(f"{len(view) - offset} unexpected bytes after the arrays")
    return header, arrays

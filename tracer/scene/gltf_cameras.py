"""A glTF file's cameras as the scene's view: a perspective camera's ``yfov`` and its node's
placement (the camera looks down the node's -Z, +Y up). Orthographic cameras are not our
camera model: a bare file passes over them (``gltf_features`` warns), naming one is an error.
Malformed cameras raise :class:`SceneError`."""

import math
from dataclasses import dataclass

import numpy as np
import pydantic

from tracer import config
from tracer.errors import SceneError
from tracer.maths import portable
from tracer.scene import format as fmt
from tracer.scene.gltf_nodes import FileNode, finite, scene_nodes

DEFAULT_WIDTH = 640


@dataclass(frozen=True)
class FileCameraNode:
    """A node with a camera: the node, the camera's index, name (or ``cameras[i]``), type and
    ``perspective`` parameters (empty for an orthographic camera)."""

    node: FileNode
    index: int
    name: str
    kind: str
    perspective: dict


def camera_nodes(document: dict, label: str) -> list[FileCameraNode]:
    """Every node of the file's scene that holds a camera, in node order; checked."""
    cameras = document.get("cameras", [])
    if not isinstance(cameras, list):
        raise SceneError(f"{label}: cameras must be a list")
    found = []
    for node in scene_nodes(document, label):
        if "camera" not in node.spec:
            continue
        index = node.spec["camera"]
        if isinstance(index, bool) or not isinstance(index, int) or not 0 <= index < len(cameras):
            raise SceneError(
                f"{label}: node {node.name!r} uses camera {index!r}, which does not exist "
                f"({len(cameras)} cameras)"
            )
        found.append(_checked(node, index, cameras[index], f"{label}: cameras[{index}]"))
    return found


def _checked(node: FileNode, index: int, spec, where: str) -> FileCameraNode:
    spec = spec if isinstance(spec, dict) else {}
    kind = spec.get("type")
    name = spec.get("name") if isinstance(spec.get("name"), str) else f"cameras[{index}]"
    if kind == "orthographic":
        return FileCameraNode(node, index, name, kind, {})
    if kind != "perspective":
        raise SceneError(f"{where}: unknown type {kind!r} (perspective or orthographic)")
    perspective = spec.get("perspective")
    if not isinstance(perspective, dict):
        raise SceneError(f"{where}: a perspective camera needs its perspective object")
    yfov = perspective.get("yfov")
    if not finite(yfov) or not 0.0 < yfov < math.pi:
        raise SceneError(f"{where}: yfov must be a number of radians in (0, pi), not {yfov!r}")
    aspect = perspective.get("aspectRatio", 1.0)
    if not finite(aspect) or not 0.0 < aspect < math.inf:
        raise SceneError(f"{where}: aspectRatio must be a number > 0, not {aspect!r}")
    return FileCameraNode(node, index, name, kind, perspective)


def view(entry: FileCameraNode, placement: np.ndarray, where: str, **image) -> fmt.Camera:
    """The scene camera of a perspective ``entry`` in the frame ``placement`` puts the file
    in; ``image`` gives the camera's other keys (width, height, aperture_radius, ...)."""
    matrix = portable.chain(placement, entry.node.matrix)
    position = matrix[:3, 3]
    forward = -matrix[:3, 2]
    if not portable.norm(forward) > 0.0:
        raise SceneError(f"{where}: node {entry.node.name!r} scales its z axis to nothing")
    try:
        return fmt.Camera(
            position=tuple(float(c) for c in position),
            look_at=tuple(float(c) for c in position + portable.normalized(forward)),
            up=tuple(float(c) for c in matrix[:3, 1]),
            vfov_deg=math.degrees(entry.perspective["yfov"]),
            **image,
        )
    except pydantic.ValidationError as exc:
        problem = exc.errors()[0]["msg"].removeprefix("Value error, ")
        raise SceneError(f"{where}: node {entry.node.name!r}: {problem}") from None


def chosen(document: dict, label: str, name: str | None = None) -> FileCameraNode | None:
    """The camera named ``name`` (the camera's or its node's name), else the first perspective
    one; None when the file has none (or, without a name, only orthographic ones)."""
    entries = camera_nodes(document, label)
    if name is None:
        return next((e for e in entries if e.kind == "perspective"), None)
    named = [e for e in entries if name in (e.name, e.node.name)]
    if not named:
        known = ", ".join(sorted({e.node.name for e in entries})) or "none"
        raise SceneError(f"{label}: no camera or camera node is named {name!r} (nodes: {known})")
    if len(named) > 1:
        raise SceneError(f"{label}: {len(named)} cameras are named {name!r}; name a node")
    if named[0].kind != "perspective":
        raise SceneError(
            f"{label}: camera {name!r} is orthographic; only perspective cameras are supported"
        )
    return named[0]


def bare_file_camera(document: dict, label: str) -> fmt.Camera | None:
    """The view of a file that is a scene on its own: its first perspective camera, 640 pixels
    wide and as high as its ``aspectRatio`` says (480 without one); None without a camera."""
    entry = chosen(document, label)
    if entry is None:
        return None
    aspect = entry.perspective.get("aspectRatio")
    height = 480 if aspect is None else round(DEFAULT_WIDTH / aspect)
    height = min(max(height, 1), config.MAX_IMAGE_SIDE)
    where = f"{label}: cameras[{entry.index}]"
    return view(entry, np.eye(4), where, width=DEFAULT_WIDTH, height=height)

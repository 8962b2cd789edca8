"""A glTF file's node hierarchy read from its JSON: every node of the file's scene with its
matrix in the file's frame, in depth-first order (what trimesh does not keep of the nodes that
hold lights and cameras). Malformed nodes raise :class:`SceneError`."""

import math
from dataclasses import dataclass

import numpy as np

from tracer.errors import SceneError
from tracer.maths import portable
from tracer.scene.animation import trs_matrix


@dataclass(frozen=True)
class FileNode:
    """A node of the file's scene: its index, its name (or ``nodes[i]``), its JSON and its
    matrix in the file's frame (float64 4x4)."""

    index: int
    name: str
    spec: dict
    matrix: np.ndarray


def finite(value) -> bool:
    """Whether a JSON value is a finite number (not a boolean)."""
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def numbers(value, count: int, where: str) -> list[float]:
    """A JSON list of ``count`` finite numbers as floats, else a ``SceneError`` at ``where``."""
    if not isinstance(value, list) or len(value) != count:
        raise SceneError(f"{where}: expected {count} numbers")
    if not all(finite(v) for v in value):
        raise SceneError(f"{where}: expected {count} finite numbers")
    return [float(v) for v in value]


def local_matrix(spec: dict, where: str) -> np.ndarray:
    """A node's local matrix: ``matrix`` (column-major) or ``T @ R @ S``."""
    if "matrix" in spec:
        return np.array(numbers(spec["matrix"], 16, f"{where}.matrix")).reshape(4, 4).T
    translation = numbers(spec.get("translation", [0, 0, 0]), 3, f"{where}.translation")
    x, y, z, w = numbers(spec.get("rotation", [0, 0, 0, 1]), 4, f"{where}.rotation")
    if not math.hypot(x, y, z, w) > 0.0:
        raise SceneError(f"{where}.rotation: a zero quaternion is no rotation")
    scale = numbers(spec.get("scale", [1, 1, 1]), 3, f"{where}.scale")
    return trs_matrix(translation, (w, x, y, z), scale)


def _roots(document: dict, nodes: list, label: str) -> list:
    scenes = document.get("scenes")
    if isinstance(scenes, list) and scenes:
        index = document.get("scene", 0)
        if not isinstance(index, int) or not 0 <= index < len(scenes):
            raise SceneError(f"{label}: scene {index!r} does not exist")
        scene = scenes[index] if isinstance(scenes[index], dict) else {}
        return scene.get("nodes", []) if isinstance(scene.get("nodes", []), list) else []
    children = {c for n in nodes if isinstance(n, dict) for c in n.get("children", []) or []}
    return [i for i in range(len(nodes)) if i not in children]


def scene_nodes(document: dict, label: str) -> list[FileNode]:
    """Every node of the file's scene (``scene``, else the first; without scenes, every root
    node's tree), parents before children. ``label`` names the file in errors."""
    nodes = document.get("nodes", [])
    if not isinstance(nodes, list):
        raise SceneError(f"{label}: nodes must be a list")
    found: list[FileNode] = []
    seen: set[int] = set()
    stack = [(i, np.eye(4)) for i in reversed(_roots(document, nodes, label))]
    while stack:
        index, parent = stack.pop()
        where = f"{label}: nodes[{index}]"
        if isinstance(index, bool) or not isinstance(index, int) or not 0 <= index < len(nodes):
            raise SceneError(f"{label}: node {index!r} does not exist ({len(nodes)} nodes)")
        if index in seen:
            raise SceneError(f"{where} is reached twice: the node hierarchy must be a tree")
        seen.add(index)
        spec = nodes[index] if isinstance(nodes[index], dict) else {}
        matrix = portable.chain(parent, local_matrix(spec, where))
        name = spec.get("name") if isinstance(spec.get("name"), str) else f"nodes[{index}]"
        found.append(FileNode(index, name, spec, matrix))
        children = spec.get("children", []) or []
        if not isinstance(children, list):
            raise SceneError(f"{where}.children must be a list")
        stack += [(child, matrix) for child in reversed(children)]
    return found


def node_extension(node: FileNode, name: str) -> dict:
    """The node's extension ``name`` (empty when it has none)."""
    extensions = node.spec.get("extensions", {})
    value = extensions.get(name, {}) if isinstance(extensions, dict) else {}
    return value if isinstance(value, dict) else {}

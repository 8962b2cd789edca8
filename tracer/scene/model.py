"""The scene as data: meshes, materials, a node hierarchy, camera, sky and animation.

A :class:`SceneState` is immutable. Edits (``tracer.scene.ops``) produce a new state that shares
every unchanged mesh, material and node with the old one, so a renderer can keep rendering one
version while the next is prepared. The loader builds states from files; the cluster's scene
graph versions them; replicas compile them (``tracer.compiled.scene``).

Node kinds follow Reiter (ch. 3) and Bikker (3.x): ``static`` geometry never moves and is merged
into one acceleration structure; ``rigid`` nodes move as a whole (only the top level changes);
``deformable`` meshes keep their topology but move vertices (refit); ``dynamic`` meshes change
topology (rebuild).
"""

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from tracer.errors import SceneError
from tracer.maths import portable
from tracer.scene import format as fmt
from tracer.scene import vertex_normals
from tracer.scene.environment import EnvironmentMap

NodeKind = Literal["static", "rigid", "deformable", "dynamic"]
NODE_KINDS: tuple[str, ...] = ("static", "rigid", "deformable", "dynamic")


def frozen_array(values, dtype) -> np.ndarray:
    """A read-only copy of ``values``: states share arrays, so nobody may write to them."""
    array = np.array(values, dtype=dtype)
    array.setflags(write=False)
    return array


@dataclass(frozen=True, eq=False)
class Mesh:
    """Triangles in object space: ``vertices`` float64 (V, 3), ``faces`` int64 (F, 3),
    optionally ``uvs`` float64 (V, 2), texture coordinates per vertex (``u`` left to right,
    ``v`` bottom to top of an image), and optionally ``normals`` float64 (V, 3), unit shading
    normals per vertex (without them the mesh shades flat); all read-only. Build with
    :func:`make_mesh`, which validates."""

    vertices: np.ndarray
    faces: np.ndarray
    uvs: np.ndarray | None = None
    normals: np.ndarray | None = None

    @property
    def triangles(self) -> int:
        return int(self.faces.shape[0])


def placed(vertices: np.ndarray, faces: np.ndarray, matrix: np.ndarray):
    """``vertices`` moved by the affine ``matrix`` (``tracer.maths.portable``) and ``faces``,
    reversed where the matrix mirrors, so front faces stay front faces."""
    moved = portable.transform_points(vertices, matrix)
    return moved, (faces[:, ::-1] if portable.det3(matrix) < 0.0 else faces)


def make_mesh(
    vertices, faces, label: str = "mesh", uvs=None, normals=None, unit_normals: bool = False
) -> Mesh:
    """A validated mesh: at least one triangle, finite coordinates, indices in range, ``uvs``
    (if given) one finite pair per vertex, and ``normals`` (if given) one finite, non-zero
    vector per vertex, normalised here unless ``unit_normals`` says they are already."""
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces)
    if vertices.ndim != 2 or vertices.shape[1] != 3 or faces.ndim != 2 or faces.shape[1] != 3:
        raise SceneError(f"{label}: not a triangle mesh")
    if faces.shape[0] == 0:
        raise SceneError(f"{label}: the mesh has no triangles")
    if not np.isfinite(vertices).all():
        raise SceneError(f"{label}: the mesh has NaN or infinite vertex coordinates")
    if not np.issubdtype(faces.dtype, np.integer):
        raise SceneError(f"{label}: face indices must be integers")
    if faces.min() < 0 or faces.max() >= vertices.shape[0]:
        raise SceneError(f"{label}: a face refers to a vertex that does not exist")
    if uvs is not None:
        uvs = np.asarray(uvs, dtype=np.float64)
        if uvs.shape != (vertices.shape[0], 2):
            raise SceneError(
                f"{label}: UVs must be one (u, v) pair per vertex: shape ({vertices.shape[0]}, "
                f"2), not {uvs.shape}"
            )
        if not np.isfinite(uvs).all():
            raise SceneError(f"{label}: the mesh has NaN or infinite UVs")
        uvs = frozen_array(uvs, np.float64)
    if normals is not None:
        normals = vertex_normals.checked(normals, vertices.shape[0], label, unit_normals)
    return Mesh(frozen_array(vertices, np.float64), frozen_array(faces, np.int64), uvs, normals)


@dataclass(frozen=True, eq=False)
class Node:
    """One scene-graph node. ``transform`` is local (to the parent), a read-only float64 4x4
    affine matrix. ``mesh`` and ``material`` are keys of the state's tables (``None`` for a
    grouping node). Ids are stable for the life of a scene; their order is the canonical order
    of everything compiled from the scene."""

    id: int
    name: str
    parent: int | None
    transform: np.ndarray
    kind: NodeKind = "static"
    mesh: str | None = None
    material: str | None = None


def Sky(radiance=(0.0, 0.0, 0.0)) -> fmt.ConstantSky:
    """A constant sky of ``radiance`` (linear RGB; 0 = black). States hold any ``fmt.Sky``."""
    return fmt.ConstantSky(radiance=tuple(radiance))


@dataclass(frozen=True)
class NodeKey:
    """A keyframe of a node's local transform: translation, rotation as a unit quaternion
    (w, x, y, z) and scale, at ``time`` seconds."""

    time: float
    translate: tuple[float, float, float]
    rotation: tuple[float, float, float, float]
    scale: tuple[float, float, float]


@dataclass(frozen=True)
class CameraKey:
    time: float
    position: tuple[float, float, float]
    look_at: tuple[float, float, float]
    up: tuple[float, float, float]
    vfov_deg: float


@dataclass(frozen=True)
class Animation:
    """Keyframe tracks: per node id, and for the camera; played at ``fps`` for ``frames``."""

    fps: float = 24.0
    frames: int = 1
    nodes: Mapping[int, tuple[NodeKey, ...]] = field(default_factory=dict)
    camera: tuple[CameraKey, ...] = ()


@dataclass(frozen=True, eq=False)
class SceneState:
    """A whole scene at one version."""

    version: int
    meshes: Mapping[str, Mesh]
    materials: Mapping[str, fmt.Material]
    nodes: Mapping[int, Node]
    camera: fmt.Camera
    render: fmt.RenderSettings
    sky: fmt.ConstantSky | fmt.GradientSky | EnvironmentMap = field(default_factory=fmt.ConstantSky)
    """An environment sky is held with its pixels (``tracer.scene.environment``)."""
    animation: Animation | None = None
    lights: tuple[fmt.Light, ...] = ()
    """Point, spot and sun lights, in world space (emitting surfaces are materials)."""
    textures: Mapping[str, np.ndarray] = field(default_factory=dict)
    """Images by the name a material's ``texture.file`` gives: uint8 (H, W, 3), sRGB-encoded,
    row 0 the top of the image, read-only (``tracer.shading.textures``)."""

    def world_transform(self, node_id: int) -> np.ndarray:
        """The node's transform to world space: its parents' transforms times its own."""
        matrix = self.nodes[node_id].transform
        parent = self.nodes[node_id].parent
        while parent is not None:
            matrix = portable.matmul(self.nodes[parent].transform, matrix)
            parent = self.nodes[parent].parent
        return matrix

    def geometry_nodes(self) -> list[Node]:
        """Nodes that carry a mesh, in id order."""
        return [self.nodes[i] for i in sorted(self.nodes) if self.nodes[i].mesh is not None]

    def world_meshes(self) -> list["WorldMesh"]:
        """Every geometry node's triangles in world space, in id order; a mirroring transform
        reverses the winding so front faces stay front faces."""
        result = []
        for node in self.geometry_nodes():
            matrix = self.world_transform(node.id)
            mesh = self.meshes[node.mesh]
            vertices, faces = placed(mesh.vertices, mesh.faces, matrix)
            result.append(WorldMesh(node.id, node.name, vertices, faces, node.material))
        return result


@dataclass(frozen=True, eq=False)
class WorldMesh:
    """A node's triangles in world space (see :meth:`SceneState.world_meshes`)."""

    node: int
    name: str
    vertices: np.ndarray
    faces: np.ndarray
    material: str

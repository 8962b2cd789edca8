"""Edits to a scene: operations as pydantic models, commits, and their application.

A commit (Brigade, Bikker 7.3.1-7.3.4) is an ordered list of operations that takes the scene
from version ``v`` to ``v + 1``. Applying operations never mutates a state: it returns a new
:class:`SceneState` that shares every unchanged mesh, material and node *object* with the old
one (the tables are copied, their values are not), so a replica finds what changed by identity
(``new.nodes[i] is not old.nodes[i]``).

Operations are validated twice: their values when the model is built (finite numbers, array
shapes), and their references (nodes, meshes, materials) against the state as the previous
operations of the same list left it. Any failure raises :class:`SceneError` and changes nothing.

A node is referred to by its integer id or by its name, which must then be unique.
"""

import dataclasses
from collections.abc import Iterable, Mapping
from typing import Annotated, Literal

import numpy as np
import pydantic
from pydantic import BaseModel, ConfigDict, Field

from tracer.errors import SceneError, format_validation_error
from tracer.scene import format as fmt
from tracer.scene import vertex_normals
from tracer.scene.checks import check_textures
from tracer.scene.model import (
    Animation,
    Mesh,
    Node,
    NodeKind,
    SceneState,
    Sky,
    frozen_array,
    make_mesh,
)
from tracer.scene.op_fields import (
    INT64_MAX,
    Faces,
    Name,
    NodeId,
    NodeName,
    NodeRef,
    Normals,
    UVs,
    Vertices,
)


class _Op(BaseModel):
    """Base of the operation models: frozen, no unknown keys, arrays allowed."""

    model_config = ConfigDict(extra="forbid", frozen=True, arbitrary_types_allowed=True)

    def __eq__(self, other) -> bool:
        """Field by field; arrays are equal when dtype, shape and bytes are."""
        if type(other) is not type(self):
            return NotImplemented
        return all(_same(getattr(self, f), getattr(other, f)) for f in type(self).model_fields)

    def _apply(self, draft: "_Draft") -> None:
        raise NotImplementedError


def _same(a, b) -> bool:
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return (
            isinstance(a, np.ndarray)
            and isinstance(b, np.ndarray)
            and a.dtype == b.dtype
            and a.shape == b.shape
            and a.tobytes() == b.tobytes()
        )
    return a == b


class SetTransform(_Op):
    """Replace a node's local transform."""

    op: Literal["set_transform"] = "set_transform"
    node: NodeRef
    transform: fmt.Transform

    def _apply(self, draft: "_Draft") -> None:
        node = draft.node(self.node)
        draft.put_node(dataclasses.replace(node, transform=_matrix(self.transform)))


class SetMaterial(_Op):
    """Add a material definition or replace one. A texture must name one of the scene's images
    (``texture.file`` as the scene loaded it)."""

    op: Literal["set_material"] = "set_material"
    name: Name
    material: fmt.Material

    def _apply(self, draft: "_Draft") -> None:
        draft.table("materials")[self.name] = self.material


class AssignMaterial(_Op):
    """Give a mesh node another (existing) material."""

    op: Literal["assign_material"] = "assign_material"
    node: NodeRef
    material: Name

    def _apply(self, draft: "_Draft") -> None:
        node = draft.node(self.node)
        if node.mesh is None:
            raise SceneError(f"node {node.id} ({node.name!r}) has no mesh to take a material")
        draft.material(self.material)
        draft.put_node(dataclasses.replace(node, material=self.material))


class SetLight(_Op):
    """Set the emitted radiance of an existing material (how lights are dimmed)."""

    op: Literal["set_light"] = "set_light"
    material: Name
    emission: fmt.Radiance

    def _apply(self, draft: "_Draft") -> None:
        material = draft.material(self.material)
        if "emission" not in type(material).model_fields:
            raise SceneError(f"material {self.material!r} is {material.type}, which cannot emit")
        changed = material.model_copy(update={"emission": self.emission})
        draft.table("materials")[self.material] = changed


class SetCamera(_Op):
    """Replace the camera."""

    op: Literal["set_camera"] = "set_camera"
    camera: fmt.Camera

    def _apply(self, draft: "_Draft") -> None:
        draft.camera = self.camera


class SetSky(_Op):
    """Set the sky: ``radiance`` for a constant sky (linear RGB; 0 = black), or a constant or
    gradient ``sky`` model of the scene format (one of the two). An environment map comes only
    with a scene file, which carries its image."""

    op: Literal["set_sky"] = "set_sky"
    radiance: fmt.Radiance | None = None
    sky: fmt.Sky | None = None

    @pydantic.model_validator(mode="after")
    def _one(self) -> "SetSky":
        if (self.radiance is None) == (self.sky is None):
            raise ValueError("give either radiance or sky")
        if isinstance(self.sky, fmt.EnvironmentSky):
            raise ValueError(
                "set_sky takes a constant or gradient sky; an environment map needs its image, "
                "which only a scene file can bring"
            )
        return self

    def _apply(self, draft: "_Draft") -> None:
        draft.sky = Sky(self.radiance) if self.sky is None else self.sky


class SetLights(_Op):
    """Replace the point, spot and sun lights (world space)."""

    op: Literal["set_lights"] = "set_lights"
    lights: list[fmt.Light]

    def _apply(self, draft: "_Draft") -> None:
        draft.lights = tuple(self.lights)


class SetRender(_Op):
    """Replace the render settings."""

    op: Literal["set_render"] = "set_render"
    render: fmt.RenderSettings

    def _apply(self, draft: "_Draft") -> None:
        draft.render = self.render


class AddMesh(_Op):
    """Add a mesh under a new name (``uvs``: texture coordinates per vertex, ``normals``:
    shading normals per vertex; both optional)."""

    op: Literal["add_mesh"] = "add_mesh"
    mesh: Name
    vertices: Vertices
    faces: Faces
    uvs: UVs | None = None
    normals: Normals | None = None

    def _apply(self, draft: "_Draft") -> None:
        if self.mesh in draft.meshes:
            raise SceneError(f"mesh {self.mesh!r} already exists (replace_mesh changes it)")
        draft.table("meshes")[self.mesh] = make_mesh(
            self.vertices, self.faces, _label(self.mesh), self.uvs, self.normals
        )


class RemoveMesh(_Op):
    """Remove a mesh no node uses."""

    op: Literal["remove_mesh"] = "remove_mesh"
    mesh: Name

    def _apply(self, draft: "_Draft") -> None:
        draft.mesh(self.mesh)
        users = [node for node in draft.nodes.values() if node.mesh == self.mesh]
        if users:
            first = users[0]
            more = f" and {len(users) - 1} more" if len(users) > 1 else ""
            raise SceneError(
                f"mesh {self.mesh!r} is used by node {first.id} ({first.name!r}){more}"
            )
        del draft.table("meshes")[self.mesh]


class UpdateVertices(_Op):
    """Move a mesh's vertices, keeping its faces and UVs (a deformable mesh). The new mesh
    shares the old one's face and UV arrays. A mesh with shading normals takes ``normals`` if
    given, else gets smooth ones computed from its moved triangles
    (``vertex_normals.area_weighted``); a flat mesh stays flat."""

    op: Literal["update_vertices"] = "update_vertices"
    mesh: Name
    vertices: Vertices
    normals: Normals | None = None

    def _apply(self, draft: "_Draft") -> None:
        mesh = draft.mesh(self.mesh)
        have, got = mesh.vertices.shape[0], self.vertices.shape[0]
        if got != have:
            raise SceneError(f"mesh {self.mesh!r} has {have} vertices, got {got}")
        label = _label(self.mesh)
        if self.normals is not None:
            normals = vertex_normals.checked(self.normals, have, label)
        elif mesh.normals is not None:
            normals = vertex_normals.area_weighted(self.vertices, mesh.faces, mesh.normals)
        else:
            normals = None
        # Same count, faces already valid and vertices already checked: nothing to revalidate.
        draft.table("meshes")[self.mesh] = Mesh(self.vertices, mesh.faces, mesh.uvs, normals)


class ReplaceMesh(_Op):
    """Replace a mesh's vertices, faces, UVs and normals (a dynamic mesh: its topology
    changes)."""

    op: Literal["replace_mesh"] = "replace_mesh"
    mesh: Name
    vertices: Vertices
    faces: Faces
    uvs: UVs | None = None
    normals: Normals | None = None

    def _apply(self, draft: "_Draft") -> None:
        draft.mesh(self.mesh)
        draft.table("meshes")[self.mesh] = make_mesh(
            self.vertices, self.faces, _label(self.mesh), self.uvs, self.normals
        )


class AddNode(_Op):
    """Add a node: a grouping node (no mesh, no material) or a mesh node (both). ``id``
    defaults to one more than the largest id in use (0 in an empty scene)."""

    op: Literal["add_node"] = "add_node"
    id: NodeId | None = None
    name: NodeName
    parent: NodeRef | None = None
    transform: fmt.Transform = fmt.Transform()
    kind: NodeKind
    mesh: Name | None = None
    material: Name | None = None

    def _apply(self, draft: "_Draft") -> None:
        node_id = draft.next_id() if self.id is None else self.id
        if node_id in draft.nodes:
            raise SceneError(f"node id {node_id} is already in use")
        parent = None if self.parent is None else draft.node(self.parent).id
        if self.mesh is not None:
            draft.mesh(self.mesh)
            if self.material is None:
                raise SceneError(f"node {self.name!r} has a mesh but no material")
        elif self.material is not None:
            raise SceneError(f"node {self.name!r} has a material but no mesh")
        if self.material is not None:
            draft.material(self.material)
        node = Node(
            node_id, self.name, parent, _matrix(self.transform), self.kind, self.mesh, self.material
        )
        draft.put_node(node, renamed=True)


class RemoveNode(_Op):
    """Remove a node with its whole subtree (and their animation tracks)."""

    op: Literal["remove_node"] = "remove_node"
    node: NodeRef

    def _apply(self, draft: "_Draft") -> None:
        draft.remove_subtree(draft.node(self.node).id)


class SetKind(_Op):
    """Change how a node may change (static, rigid, deformable, dynamic)."""

    op: Literal["set_kind"] = "set_kind"
    node: NodeRef
    kind: NodeKind

    def _apply(self, draft: "_Draft") -> None:
        draft.put_node(dataclasses.replace(draft.node(self.node), kind=self.kind))


OP_TYPES: tuple[type[_Op], ...] = (
    SetTransform,
    SetMaterial,
    AssignMaterial,
    SetLight,
    SetCamera,
    SetSky,
    SetLights,
    SetRender,
    AddMesh,
    RemoveMesh,
    UpdateVertices,
    ReplaceMesh,
    AddNode,
    RemoveNode,
    SetKind,
)
Op = Annotated[
    SetTransform
    | SetMaterial
    | AssignMaterial
    | SetLight
    | SetCamera
    | SetSky
    | SetLights
    | SetRender
    | AddMesh
    | RemoveMesh
    | UpdateVertices
    | ReplaceMesh
    | AddNode
    | RemoveNode
    | SetKind,
    Field(discriminator="op"),
]
"""Any operation; the field ``op`` names its kind."""
OP_KINDS: dict[str, type[_Op]] = {t.model_fields["op"].default: t for t in OP_TYPES}


def _matrix(transform: fmt.Transform) -> np.ndarray:
    return frozen_array(transform.to_matrix(), np.float64)


def _label(mesh: str) -> str:
    return f"mesh {mesh!r}"


class _Draft:
    """A state being edited by operations: tables are copied on first write (never their
    values), then :meth:`result` freezes the edits into a new :class:`SceneState`."""

    def __init__(self, state: SceneState) -> None:
        self._state = state
        self.meshes: Mapping[str, Mesh] = state.meshes
        self.materials: Mapping[str, fmt.Material] = state.materials
        self.nodes: Mapping[int, Node] = state.nodes
        self.camera, self.render, self.sky = state.camera, state.render, state.sky
        self.lights = state.lights
        self.animation: Animation | None = state.animation
        self._copied: set[str] = set()
        self._names: dict[str, list[int]] | None = None

    def table(self, name: str) -> dict:
        """The draft's own (writable) copy of the table ``meshes``, ``materials`` or ``nodes``."""
        if name not in self._copied:
            setattr(self, name, dict(getattr(self, name)))
            self._copied.add(name)
        return getattr(self, name)

    def node(self, ref: int | str) -> Node:
        """The node an id or a unique name refers to."""
        if isinstance(ref, int):
            if ref not in self.nodes:
                raise SceneError(f"node {ref} does not exist")
            return self.nodes[ref]
        if self._names is None:
            self._names = {}
            for node in self.nodes.values():
                self._names.setdefault(node.name, []).append(node.id)
        ids = self._names.get(ref, [])
        if not ids:
            raise SceneError(f"no node is named {ref!r}")
        if len(ids) > 1:
            listed = ", ".join(str(i) for i in sorted(ids))
            raise SceneError(f"{len(ids)} nodes are named {ref!r} (ids {listed}): use an id")
        return self.nodes[ids[0]]

    def mesh(self, name: str) -> Mesh:
        if name not in self.meshes:
            raise SceneError(f"mesh {name!r} does not exist")
        return self.meshes[name]

    def material(self, name: str) -> fmt.Material:
        if name not in self.materials:
            raise SceneError(f"material {name!r} does not exist")
        return self.materials[name]

    def put_node(self, node: Node, renamed: bool = False) -> None:
        """Store ``node`` under its id; ``renamed`` when names may have changed."""
        self.table("nodes")[node.id] = node
        if renamed:
            self._names = None

    def next_id(self) -> int:
        next_id = max(self.nodes, default=-1) + 1
        if next_id > INT64_MAX:
            raise SceneError("no node id left above the largest one: give an id")
        return next_id

    def remove_subtree(self, root: int) -> None:
        children: dict[int, list[int]] = {}
        for node in self.nodes.values():
            if node.parent is not None:
                children.setdefault(node.parent, []).append(node.id)
        removed, pending = set(), [root]
        while pending:
            node_id = pending.pop()
            removed.add(node_id)
            pending.extend(children.get(node_id, ()))
        nodes = self.table("nodes")
        for node_id in removed:
            del nodes[node_id]
        self._names = None
        if self.animation is not None and not removed.isdisjoint(self.animation.nodes):
            tracks = {i: k for i, k in self.animation.nodes.items() if i not in removed}
            self.animation = dataclasses.replace(self.animation, nodes=tracks)

    def result(self) -> SceneState:
        """The edited state (same version as the original)."""
        return dataclasses.replace(
            self._state,
            meshes=self.meshes,
            materials=self.materials,
            nodes=self.nodes,
            camera=self.camera,
            render=self.render,
            sky=self.sky,
            animation=self.animation,
            lights=self.lights,
        )


def apply_ops(state: SceneState, ops: Iterable[Op]) -> SceneState:
    """``state`` with ``ops`` applied in order; it keeps ``state.version``.

    Raises SceneError naming the failing op's index and kind, or for textures the ops leave
    without their image or UVs (``scene_check.check_textures``); the input is left as it was.
    """
    draft = _Draft(state)
    for index, op in enumerate(ops):
        if not isinstance(op, OP_TYPES):
            raise SceneError(f"op {index}: not an operation model ({type(op).__name__})")
        try:
            op._apply(draft)
        except SceneError as error:
            raise SceneError(f"op {index} ({op.op}): {error}") from error
    result = draft.result()
    check_textures(result)
    return result


def parse_op(data: Mapping | Op) -> Op:
    """The operation a JSON-like dict describes (an operation model is returned as it is)."""
    return _parse(data, "op")


def parse_ops(items: Iterable[Mapping | Op]) -> tuple[Op, ...]:
    """:func:`parse_op` for each item; errors name the item's index."""
    return tuple(_parse(item, f"op {index}") for index, item in enumerate(items))


def _parse(data, where: str) -> _Op:
    if isinstance(data, OP_TYPES):
        return data
    if not isinstance(data, Mapping):
        raise SceneError(f"{where}: an operation is an object, not {type(data).__name__}")
    kind = data.get("op")
    if not isinstance(kind, str) or kind not in OP_KINDS:
        known = ", ".join(OP_KINDS)
        raise SceneError(f"{where}: unknown operation {kind!r} (known: {known})")
    # Imported here: the loader may build animated scenes with tracer.scene.animation, which imports
    # this module, so a module-level import of the loader would be circular.
    try:
        return OP_KINDS[kind].model_validate(data)
    except pydantic.ValidationError as error:
        raise SceneError(f"{where} ({kind}): {format_validation_error(error)}") from None


@dataclasses.dataclass(frozen=True)
class Commit:
    """The operations that take a scene to ``version`` from ``version - 1``."""

    version: int
    ops: tuple[Op, ...]

    def __post_init__(self) -> None:
        object.__setattr__(self, "ops", tuple(self.ops))


class CommitGap(SceneError):
    """A commit does not follow the replica's version: the replica needs a snapshot."""


def apply_commit(state: SceneState, commit: Commit) -> SceneState:
    """``state`` moved to ``commit.version``; a commit already applied changes nothing."""
    if commit.version <= state.version:
        return state
    if commit.version != state.version + 1:
        raise CommitGap(
            f"commit {commit.version} cannot follow version {state.version} "
            f"(commits {state.version + 1}..{commit.version - 1} are missing): take a snapshot"
        )
    return dataclasses.replace(apply_ops(state, commit.ops), version=commit.version)

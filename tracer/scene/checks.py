"""The invariants of a :class:`~tracer.scene.model.SceneState`, checked in one place.

Operations (``tracer.scene.ops``) keep these invariants one edit at a time; this module checks a
whole state that arrives from elsewhere: a decoded snapshot, or the initial state of the
cluster's scene graph. Every violation raises :class:`SceneError` naming the first problem.
"""

import itertools
import math

import numpy as np

from tracer import config
from tracer.errors import SceneError
from tracer.maths import portable
from tracer.scene import format as fmt
from tracer.scene.environment import EnvironmentMap, check_image
from tracer.scene.model import NODE_KINDS, Animation, Mesh, Node, SceneState
from tracer.shading.textures import alpha_texture, material_texture


def check_state(state: SceneState) -> None:
    """Raise SceneError unless ``state`` is a consistent scene: typed tables, node references
    that exist, an acyclic hierarchy, affine non-singular transforms, sane animation, and
    textures that exist on meshes with UVs."""
    if not isinstance(state.version, int) or isinstance(state.version, bool):
        raise SceneError(f"version must be an integer, not {state.version!r}")
    for name, mesh in state.meshes.items():
        if not isinstance(name, str) or not isinstance(mesh, Mesh):
            raise SceneError(f"meshes[{name!r}] is not a named Mesh")
    for name, material in state.materials.items():
        if not isinstance(name, str) or not isinstance(material, fmt.MATERIAL_TYPES):
            raise SceneError(f"materials[{name!r}] is not a named material")
    if not isinstance(state.camera, fmt.Camera) or not isinstance(state.render, fmt.RenderSettings):
        raise SceneError("camera and render must be scene_format models")
    if isinstance(state.sky, EnvironmentMap):
        if not isinstance(state.sky.model, fmt.EnvironmentSky):
            raise SceneError("an environment map's model must be a scene_format EnvironmentSky")
        if not isinstance(state.sky.image, np.ndarray) or state.sky.image.dtype != np.float32:
            raise SceneError("an environment map's image must be a float32 array")
        check_image(state.sky.image, f"sky: {state.sky.model.file}")
    elif not isinstance(state.sky, fmt.ConstantSky | fmt.GradientSky):
        raise SceneError(
            f"the sky must be a constant or gradient sky model or an environment map with its "
            f"image, not {state.sky!r}"
        )
    if not all(isinstance(light, fmt.PointLight | fmt.SpotLight | fmt.SunLight) for light in
               state.lights):  # fmt: skip
        raise SceneError("lights must be scene_format light models")
    _check_nodes(state)
    if state.animation is not None:
        _check_animation(state.animation, state.nodes)
    for name, pixels in state.textures.items():
        if not (
            isinstance(name, str)
            and isinstance(pixels, np.ndarray)
            and pixels.dtype == np.uint8
            and pixels.ndim == 3
            and pixels.shape[2] == 3
            and 0 < pixels.shape[0] <= config.MAX_TEXTURE_SIDE
            and 0 < pixels.shape[1] <= config.MAX_TEXTURE_SIDE
            and pixels.shape[0] * pixels.shape[1] <= config.MAX_TEXTURE_PIXELS
        ):
            raise SceneError(f"textures[{name!r}] is not a named uint8 (H, W, 3) image in limits")
    check_textures(state)


def check_textures(state: SceneState) -> None:
    """Raise SceneError unless every texture, normal map and alpha texture a material names is
    one of the state's images (an alpha texture's alpha channel: ``alpha_image_name``) and
    every mesh node whose material has one has UVs."""
    textured = {}
    for name, material in state.materials.items():
        alpha = alpha_texture(material)
        named = (("texture", material_texture(material)),
                 ("normal map", getattr(material, "normal_map", None)),
                 ("alpha texture", alpha))  # fmt: skip
        for label, texture in named:
            if texture is None:
                continue
            if texture.file not in state.textures:
                if texture is alpha:
                    raise SceneError(
                        f"material {name!r}: the alpha channel of its alpha texture "
                        f"{material.alpha.texture.file!r} is not among the scene's images (an "
                        "image used as an alpha texture must be loaded with the scene)"
                    )
                raise SceneError(
                    f"material {name!r}: its {label} {texture.file!r} is not one of the "
                    "scene's images"
                )
            textured.setdefault(name, label)
    if not textured:
        return
    for node in state.nodes.values():
        if node.material in textured and state.meshes[node.mesh].uvs is None:
            raise SceneError(
                f"{node.name or f'node {node.id}'}: material {node.material!r} has a "
                f"{textured[node.material]}, but the mesh has no UVs (texture coordinates)"
            )


def _check_nodes(state: SceneState) -> None:
    for key, node in state.nodes.items():
        if not isinstance(node, Node) or node.id != key:
            raise SceneError(f"nodes[{key!r}] is not a Node with id {key!r}")
        where = f"node {key} ({node.name!r})"
        if node.parent is not None and node.parent not in state.nodes:
            raise SceneError(f"{where}: parent {node.parent!r} does not exist")
        if node.kind not in NODE_KINDS:
            raise SceneError(f"{where}: kind {node.kind!r} is not one of {', '.join(NODE_KINDS)}")
        if node.mesh is not None and node.mesh not in state.meshes:
            raise SceneError(f"{where}: mesh {node.mesh!r} does not exist")
        if node.material is not None and node.material not in state.materials:
            raise SceneError(f"{where}: material {node.material!r} does not exist")
        if (node.mesh is None) != (node.material is None):
            raise SceneError(f"{where}: a node has both a mesh and a material, or neither")
    _check_acyclic(state.nodes)
    if state.nodes:
        _check_transforms(state.nodes)


def _check_acyclic(nodes) -> None:
    rooted: set[int] = set()
    for start in nodes:
        path: list[int] = []
        on_path: set[int] = set()
        current = start
        while current is not None and current not in rooted:
            if current in on_path:
                raise SceneError(f"node {current}: the parent chain loops back to itself")
            path.append(current)
            on_path.add(current)
            current = nodes[current].parent
        rooted.update(path)


def _check_transforms(nodes) -> None:
    ids = list(nodes)
    transforms = [np.asarray(nodes[i].transform) for i in ids]
    for node_id, matrix in zip(ids, transforms, strict=True):
        if matrix.shape != (4, 4) or matrix.dtype != np.float64:
            raise SceneError(f"node {node_id}: transform must be a float64 4x4 matrix")
    stack = np.stack(transforms)
    with np.errstate(all="ignore"):  # overflow shows up as a non-finite determinant
        dets = portable.det3(stack)
    bad = ~np.isfinite(stack).all(axis=(1, 2)) | (stack[:, 3] != [0.0, 0.0, 0.0, 1.0]).any(axis=1)
    bad |= ~np.isfinite(dets) | (dets == 0.0)
    if bad.any():
        node_id = ids[int(np.argmax(bad))]
        raise SceneError(f"node {node_id}: transform is not a finite, affine, non-singular matrix")


def _check_animation(animation: Animation, nodes) -> None:
    if not (_finite(animation.fps) and animation.fps > 0.0):
        raise SceneError(f"animation fps must be a positive number, not {animation.fps!r}")
    if not isinstance(animation.frames, int) or animation.frames < 1:
        raise SceneError(f"animation frames must be a positive integer, not {animation.frames!r}")
    for node_id, keys in animation.nodes.items():
        where = f"animation of node {node_id!r}"
        if node_id not in nodes:
            raise SceneError(f"{where}: the node does not exist")
        if not keys:
            raise SceneError(f"{where}: a track needs at least one key")
        _check_times(where, keys)
        for key in keys:
            if not _finite_vector(key.translate, 3) or not _finite_vector(key.scale, 3):
                raise SceneError(f"{where}: translate and scale must be three finite numbers")
            if 0.0 in key.scale:
                raise SceneError(f"{where}: a key has a zero scale")
            if not _finite_vector(key.rotation, 4) or not any(key.rotation):
                raise SceneError(f"{where}: rotation must be a finite non-zero quaternion")
    _check_times("camera animation", animation.camera)
    for key in animation.camera:
        vectors = (key.position, key.look_at, key.up)
        if not all(_finite_vector(v, 3) for v in vectors) or not 0.0 < key.vfov_deg < 180.0:
            raise SceneError("camera animation: a key has non-finite vectors or a bad vfov")


def _check_times(where: str, keys) -> None:
    times = [key.time for key in keys]
    if not all(_finite(t) for t in times) or any(a > b for a, b in itertools.pairwise(times)):
        raise SceneError(f"{where}: key times must be finite and never decrease")


def _finite(value) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def _finite_vector(values, length: int) -> bool:
    return len(values) == length and all(_finite(v) for v in values)

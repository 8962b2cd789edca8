"""``KHR_texture_transform``: a texture's offset, rotation and scale as the affine map
``T * R * S`` of glTF's UV space, applied to a mesh's UVs when it loads. UVs are interpolated
linearly over a triangle, so moving them at the vertices is exact. One map per material: its
``baseColorTexture``'s, else its ``normalTexture``'s (docs/materials.md, "glTF features")."""

import math

import numpy as np

from tracer.errors import SceneError
from tracer.scene.gltf_nodes import numbers

EXTENSION = "KHR_texture_transform"
SAMPLED = ("baseColorTexture", "normalTexture")
"""The textures read per texel, in the order their transform wins."""


def sampled_infos(spec: dict) -> dict[str, dict]:
    """A material's textureInfos of ``SAMPLED`` by key."""
    pbr = spec.get("pbrMetallicRoughness", {})
    pbr = pbr if isinstance(pbr, dict) else {}
    infos = {"baseColorTexture": pbr.get("baseColorTexture")}
    infos["normalTexture"] = spec.get("normalTexture")
    return {key: info for key, info in infos.items() if isinstance(info, dict)}


def _extension(info: dict) -> dict | None:
    extensions = info.get("extensions", {})
    value = extensions.get(EXTENSION) if isinstance(extensions, dict) else None
    return value if isinstance(value, dict) else None


def uv_matrix(info: dict, where: str) -> np.ndarray | None:
    """The 2x3 matrix of a textureInfo's transform in glTF's UV space (v down), or None."""
    transform = _extension(info)
    if transform is None:
        return None
    ox, oy = numbers(transform.get("offset", [0.0, 0.0]), 2, f"{where}.offset")
    (rotation,) = numbers([transform.get("rotation", 0.0)], 1, f"{where}.rotation")
    sx, sy = numbers(transform.get("scale", [1.0, 1.0]), 2, f"{where}.scale")
    c, s = math.cos(rotation), math.sin(rotation)
    return np.array([[c * sx, s * sy, ox], [-s * sx, c * sy, oy]])


def tex_coord(info: dict) -> int:
    """The UV set a textureInfo reads: the transform's ``texCoord`` overrides its own."""
    transform = _extension(info) or {}
    value = transform.get("texCoord", info.get("texCoord", 0))
    return value if isinstance(value, int) and not isinstance(value, bool) else 0


def material_uv_matrix(spec: dict, where: str) -> np.ndarray | None:
    """The transform a material's UVs take: that of the first of ``SAMPLED`` it has."""
    infos = sampled_infos(spec)
    for key in SAMPLED:
        if key in infos:
            return uv_matrix(infos[key], f"{where}.{key}.extensions.{EXTENSION}")
    return None


def has_transform(spec: dict) -> bool:
    """Whether a material's base-colour or normal texture has a transform."""
    return any(_extension(info) is not None for info in sampled_infos(spec).values())


def transforms_differ(spec: dict) -> bool:
    """Whether a material's base-colour and normal textures have different transforms."""
    infos = sampled_infos(spec)
    if len(infos) < 2:
        return False
    try:
        matrices = [uv_matrix(info, key) for key, info in infos.items()]
    except SceneError:
        return False
    identity = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    a, b = (identity if m is None else m for m in matrices)
    return not np.array_equal(a, b)


def transformed_uvs(uvs: np.ndarray, matrix: np.ndarray) -> np.ndarray:
    """UVs as trimesh keeps them (``v`` flipped to point up) moved by ``matrix`` (which acts
    in glTF's space, ``v`` down), flipped back."""
    u, v = uvs[:, 0], 1.0 - uvs[:, 1]
    moved_u = matrix[0, 0] * u + matrix[0, 1] * v + matrix[0, 2]
    moved_v = matrix[1, 0] * u + matrix[1, 1] * v + matrix[1, 2]
    return np.stack([moved_u, 1.0 - moved_v], axis=1)

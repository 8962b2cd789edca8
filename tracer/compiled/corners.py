"""Per-corner attributes of triangles, texture coordinates and shading normals: one row per
triangle with its three corners side by side, in a mesh's triangle order, a BVH's leaf order,
or joined over the meshes of a pool.

Normals are stored as float32 (36 bytes a triangle) and only for meshes that have them; a row
of zeros is a triangle that shades flat (the kernel falls back to its geometric normal).
"""

from typing import NamedTuple

import numpy as np

from tracer.scene import vertex_normals
from tracer.scene.model import Mesh
from tracer.shading.textures import uv_rows


class Corners(NamedTuple):
    uv: np.ndarray | None
    """float32 (T, 6): each triangle's corner UVs, or None."""
    normal: np.ndarray | None
    """float32 (T, 9): each triangle's corner shading normals, or None (flat)."""

    def ordered(self, prim: np.ndarray) -> "Corners":
        """The rows in the order ``prim`` gives (a BVH's leaf order)."""
        return Corners(*(None if rows is None else rows[prim] for rows in self))


NO_CORNERS = Corners(None, None)


def moved_normals(normals: np.ndarray, matrix: np.ndarray) -> np.ndarray:
    """Unit normals carried by the affine ``matrix`` (``vertex_normals.transformed``), zeros
    where it flattens them."""
    moved = vertex_normals.transformed(normals, matrix)
    length = np.sqrt(moved[:, 0] ** 2 + moved[:, 1] ** 2 + moved[:, 2] ** 2)
    ok = length > 0.0
    out = np.zeros_like(moved)
    out[ok] = moved[ok] / length[ok, None]
    return out


def mesh_corners(mesh: Mesh, faces: np.ndarray | None = None, matrix=None) -> Corners:
    """The corner rows of ``mesh``'s triangles ``faces`` (its own by default), normals carried
    by ``matrix`` when given (baked static geometry is in world space)."""
    faces = mesh.faces if faces is None else faces
    uv = None if mesh.uvs is None else uv_rows(mesh.uvs, faces)
    normal = None
    if mesh.normals is not None:
        normals = mesh.normals if matrix is None else moved_normals(mesh.normals, matrix)
        normal = np.ascontiguousarray(normals[faces].reshape(-1, 9), dtype=np.float32)
    return Corners(uv, normal)


def joined(parts: list[Corners], counts: list[int]) -> Corners:
    """The rows of meshes with ``counts`` triangles each, concatenated: zeros for a mesh
    without the attribute, None when no mesh has it."""
    rows = []
    for attribute, width in ((0, 6), (1, 9)):
        given = [p[attribute] for p in parts]
        if all(r is None for r in given):
            rows.append(None)
            continue
        rows.append(np.concatenate([np.zeros((n, width), np.float32) if r is None else r
                                    for r, n in zip(given, counts, strict=True)]))  # fmt: skip
    return Corners(*rows)

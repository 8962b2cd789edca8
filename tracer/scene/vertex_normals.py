"""Shading normals per vertex: checking the ones a user or a file gives, and computing smooth
ones from the triangles (for a deformed mesh whose normals must follow its vertices).

Arithmetic is element by element, or accumulations in face order (``np.add.at``): never a
reduction whose order could depend on the CPU, so the same mesh gives the same normals on every
machine.
"""

import math

import numpy as np

from tracer.errors import SceneError
from tracer.maths import portable


def _lengths(vectors: np.ndarray) -> np.ndarray:
    return np.sqrt(vectors[:, 0] ** 2 + vectors[:, 1] ** 2 + vectors[:, 2] ** 2)


def _frozen(array: np.ndarray) -> np.ndarray:
    array = np.ascontiguousarray(array, dtype=np.float64)
    array.setflags(write=False)
    return array


def checked(normals, vertex_count: int, label: str, unit: bool = False) -> np.ndarray:
    """``normals`` checked (one finite, non-zero vector per vertex) and scaled to unit length,
    read-only; SceneError otherwise. ``unit``: they are unit already (a state's, decoded) and
    are kept bit for bit (normalising twice may move the last bit)."""
    normals = np.asarray(normals, dtype=np.float64)
    if normals.shape != (vertex_count, 3):
        raise SceneError(
            f"{label}: normals must be one (x, y, z) vector per vertex: shape ({vertex_count}, "
            f"3), not {normals.shape}"
        )
    if not np.isfinite(normals).all():
        raise SceneError(f"{label}: the mesh has NaN or infinite normals")
    length = _lengths(normals)
    if unit:
        if not (np.abs(length - 1.0) < 1e-9).all():
            raise SceneError(f"{label}: a stored vertex normal is not of unit length")
        return _frozen(normals)
    if not (length > 1e-12).all():
        raise SceneError(f"{label}: a vertex normal has zero length")
    return _frozen(normals / length[:, None])


def area_weighted(vertices: np.ndarray, faces: np.ndarray, fallback: np.ndarray) -> np.ndarray:
    """Unit normals per vertex: the sum of the normals of the faces around it, each weighted by
    its area (the cross product of two edges), in face order. A vertex whose faces have no
    area keeps its normal from ``fallback`` (V, 3)."""
    a, b, c = (vertices[faces[:, i]] for i in range(3))
    face_normal = np.cross(b - a, c - a)
    total = np.zeros_like(vertices, dtype=np.float64)
    for corner in range(3):
        np.add.at(total, faces[:, corner], face_normal)
    length = _lengths(total)
    ok = length > 0.0
    result = np.array(fallback, dtype=np.float64)
    result[ok] = total[ok] / length[ok, None]
    return _frozen(result)


def transformed(normals: np.ndarray, matrix: np.ndarray) -> np.ndarray:
    """``normals`` moved by the affine ``matrix`` as normals move: by the inverse transpose of
    its 3x3 block, computed as the cofactor matrix times the determinant's sign (the same
    direction, no division), element by element. Not normalised; a singular matrix may give
    zero vectors (see :func:`repaired`)."""
    m = np.asarray(matrix, dtype=np.float64)
    a, b, c = m[:3, 0], m[:3, 1], m[:3, 2]
    cofactor = np.stack([portable.cross(b, c), portable.cross(c, a), portable.cross(a, b)], 1)
    sign = -1.0 if portable.det3(m) < 0.0 else 1.0
    return portable.transform_vectors(normals, cofactor) * sign


def repaired(normals, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """A file's ``normals`` with each NaN, infinite or zero-length one replaced by the vertex's
    area-weighted normal (+z where that has no length either: no face of area uses it)."""
    normals = np.array(normals, dtype=np.float64)
    with np.errstate(invalid="ignore", over="ignore"):
        bad = ~(np.isfinite(normals).all(axis=1) & (_lengths(normals) > 1e-12))
    if bad.any():
        fallback = np.zeros_like(normals)
        fallback[:, 2] = 1.0
        normals[bad] = area_weighted(vertices, faces, fallback)[bad]
    return normals


def creased(vertices: np.ndarray, faces: np.ndarray, angle_deg: float):
    """Smooth normals that keep creases: two faces that share an edge (vertices compared by
    position, so a triangle soup works too) and whose normals differ by less than
    ``angle_deg`` are smoothed across it; each vertex gets, per fan of faces joined that way
    around it, the area-weighted sum of their normals, and is split where it has several.

    Returns ``(source, faces, normals)``: the vertex each new vertex copies (so UVs follow
    the split), the faces on the new vertices and their unit normals (V', 3). Face corners
    of zero area keep the vertex's area-weighted normal."""
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    if len(faces) == 0:
        return np.zeros(0, np.int64), faces, _frozen(np.zeros((0, 3)))
    _, position = np.unique(vertices + 0.0, axis=0, return_inverse=True)
    at = position.reshape(-1)[faces]  # (F, 3) position ids
    a, b, c = (vertices[faces[:, i]] for i in range(3))
    face_normal = np.cross(b - a, c - a)
    length = _lengths(face_normal)
    unit = np.zeros_like(face_normal)
    np.divide(face_normal, length[:, None], out=unit, where=length[:, None] > 0.0)
    corners = _joined_corners(at, unit, length > 0.0, math.cos(math.radians(angle_deg)))
    total = np.zeros((corners.max() + 1, 3))
    np.add.at(total, corners, np.repeat(face_normal, 3, axis=0))
    groups = np.stack([faces.reshape(-1), corners], axis=1)
    split, corner_vertex = np.unique(groups, axis=0, return_inverse=True)
    normals = total[split[:, 1]]
    fallback = np.zeros_like(vertices)
    fallback[:, 2] = 1.0
    smooth = area_weighted(vertices, faces, fallback)[split[:, 0]]
    ok = _lengths(normals) > 0.0
    normals[~ok] = smooth[~ok]
    normals[ok] /= _lengths(normals[ok])[:, None]
    return split[:, 0], corner_vertex.reshape(-1, 3), _frozen(normals)


def _joined_corners(at: np.ndarray, unit: np.ndarray, has_area: np.ndarray, cos_limit: float):
    """A group label per face corner (F * 3, corner ``3 f + k``): the corners at one position of
    two faces joined across an edge they share (both of area, normals at a cosine above
    ``cos_limit``) get one label. On an edge of more than two faces, faces are joined to the
    next one in face order."""
    corner = np.arange(at.size)
    start = at.reshape(-1)
    end = at[:, [1, 2, 0]].reshape(-1)
    at_end = corner - corner % 3 + (corner % 3 + 1) % 3
    low, high = np.minimum(start, end), np.maximum(start, end)
    at_low = np.where(start <= end, corner, at_end)
    at_high = np.where(start <= end, at_end, corner)
    order = np.lexsort((corner, high, low))  # half-edges of one edge together, in face order
    same = (low[order][1:] == low[order][:-1]) & (high[order][1:] == high[order][:-1])
    h1, h2 = order[:-1][same], order[1:][same]
    f, g = h1 // 3, h2 // 3
    dots = unit[f, 0] * unit[g, 0] + unit[f, 1] * unit[g, 1] + unit[f, 2] * unit[g, 2]
    keep = has_area[f] & has_area[g] & (dots > cos_limit)
    h1, h2 = h1[keep], h2[keep]
    return _components(
        at.size,
        np.concatenate([at_low[h1], at_high[h1]]),
        np.concatenate([at_low[h2], at_high[h2]]),
    )


def _components(count: int, first: np.ndarray, second: np.ndarray) -> np.ndarray:
    """Connected components of ``count`` nodes joined pairwise (``first[i]``, ``second[i]``),
    each labelled by its smallest node: union by hooking roots onto smaller ones, then
    pointer jumping (integers only, so the same on every machine)."""
    parent = np.arange(count)
    while True:
        root_a, root_b = parent[first], parent[second]
        differ = root_a != root_b
        if not differ.any():
            return parent
        np.minimum.at(
            parent, np.maximum(root_a, root_b)[differ], np.minimum(root_a, root_b)[differ]
        )
        while True:
            jumped = parent[parent]
            if (jumped == parent).all():
                break
            parent = jumped

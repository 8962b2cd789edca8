"""Shading normals per vertex: checking the ones a user or a file gives, and computing smooth
ones from the triangles (for a deformed mesh whose normals must follow its vertices).

Arithmetic is element by element, or accumulations in face order (``np.add.at``): never a
reduction whose order could depend on the CPU, so the same mesh gives the same normals on every
machine.
"""

import numpy as np

from tracer.errors import SceneError


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

"""Triangles of zero area: found exactly on the float32 coordinates kernels use, and the reason
a mesh with nothing else is refused (degenerate as given, as placed, or in float32)."""

from fractions import Fraction

import numpy as np

from tracer.kernel.jit import jit


@jit
def _zero_area_screen(tri_verts):
    """Per triangle: a repeated vertex (degenerate outright), and whether float64 cannot rule
    out collinearity (a cross product tiny against the edges)."""
    n = tri_verts.shape[0]
    repeated = np.zeros(n, np.bool_)
    candidate = np.zeros(n, np.bool_)
    for i in range(n):
        p = tri_verts[i]
        same01 = p[0] == p[3] and p[1] == p[4] and p[2] == p[5]
        same12 = p[3] == p[6] and p[4] == p[7] and p[5] == p[8]
        same20 = p[6] == p[0] and p[7] == p[1] and p[8] == p[2]
        if same01 or same12 or same20:
            repeated[i] = True
            continue
        a0 = np.float64(p[3]) - np.float64(p[0])
        a1 = np.float64(p[4]) - np.float64(p[1])
        a2 = np.float64(p[5]) - np.float64(p[2])
        b0 = np.float64(p[6]) - np.float64(p[0])
        b1 = np.float64(p[7]) - np.float64(p[1])
        b2 = np.float64(p[8]) - np.float64(p[2])
        size = max(abs(a1 * b2 - a2 * b1), max(abs(a2 * b0 - a0 * b2), abs(a0 * b1 - a1 * b0)))
        scale = max(abs(a0), max(abs(a1), abs(a2))) * max(abs(b0), max(abs(b1), abs(b2)))
        candidate[i] = size <= 1e-9 * scale
    return repeated, candidate


def zero_area_mask(tri_verts: np.ndarray) -> np.ndarray:
    """Triangles whose float32 vertices are exactly collinear (or repeated).

    Triangles with a repeated vertex are degenerate outright. For the rest, float64 screens out
    the clearly non-degenerate (a cross product far from zero), and every remaining candidate is
    decided exactly, with rational arithmetic on the float32 values: float64 alone is not exact
    when one triangle mixes tiny and ordinary coordinates.
    """
    mask, candidate = _zero_area_screen(np.ascontiguousarray(tri_verts, dtype=np.float32))
    for i in np.flatnonzero(candidate):
        p = [[Fraction(float(x)) for x in vertex] for vertex in tri_verts[i].reshape(3, 3)]
        a = [p[1][k] - p[0][k] for k in range(3)]
        b = [p[2][k] - p[0][k] for k in range(3)]
        mask[i] = (
            a[1] * b[2] == a[2] * b[1] and a[2] * b[0] == a[0] * b[2] and a[0] * b[1] == a[1] * b[0]
        )
    return mask


def _flat(triangles: np.ndarray) -> bool:
    """Every triangle (float64 (F, 3, 3)) has an exactly zero cross product."""
    a = triangles[:, 1] - triangles[:, 0]
    b = triangles[:, 2] - triangles[:, 0]
    return not (
        np.any(a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1])
        or np.any(a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2])
        or np.any(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])
    )


def all_zero_area(label: str, triangles: np.ndarray, given: np.ndarray | None = None) -> str:
    """Why every triangle of a mesh was dropped: degenerate as given (``given``, the mesh's own
    float64 triangles, default ``triangles``), flattened by float64 where its transform put it
    (``triangles``, as placed), or rounded flat by float32 at the mesh's own scale."""
    if _flat(triangles if given is None else given):
        return f"{label}: every triangle of the mesh has zero area"
    if _flat(triangles):
        where = float(np.max(np.abs(triangles)))
        return (
            f"{label}: its transform places it so far out ({where:.3g}) that float64 cannot tell "
            "its vertices apart; move it nearer the origin or scale the scene down"
        )
    lo = triangles.reshape(-1, 3).min(axis=0)
    hi = triangles.reshape(-1, 3).max(axis=0)
    return (
        f"{label}: its triangles are too small for float32 coordinates across the mesh's extent "
        f"({float(np.max(hi - lo)):.3g}): every one rounds to zero area; split the mesh into "
        "smaller ones"
    )

"""Affine transforms of instances, as kernels use them, with conservative error bounds.

A transform is a row of 12 float64: the 3x4 matrix ``[r00 r01 r02 t0 r10 r11 r12 t1 r20 r21 r22
t2]``. Each instance has one (object -> world) and its inverse (world -> object).
"""

import numpy as np

from tracer.geometry.intersect import GAMMA3
from tracer.kernel.jit import jit_inline
from tracer.maths import portable


def to_rows(matrix: np.ndarray) -> np.ndarray:
    """The 12-value row of a 4x4 affine matrix."""
    return np.ascontiguousarray(np.asarray(matrix, dtype=np.float64)[:3, :4].reshape(12))


@jit_inline
def apply_point(m, k, p):
    """Transform point ``p`` by row ``k`` of ``m``."""
    return (
        m[k, 0] * p[0] + m[k, 1] * p[1] + m[k, 2] * p[2] + m[k, 3],
        m[k, 4] * p[0] + m[k, 5] * p[1] + m[k, 6] * p[2] + m[k, 7],
        m[k, 8] * p[0] + m[k, 9] * p[1] + m[k, 10] * p[2] + m[k, 11],
    )


@jit_inline
def apply_vector(m, k, v):
    """Transform direction ``v`` (no translation)."""
    return (
        m[k, 0] * v[0] + m[k, 1] * v[1] + m[k, 2] * v[2],
        m[k, 4] * v[0] + m[k, 5] * v[1] + m[k, 6] * v[2],
        m[k, 8] * v[0] + m[k, 9] * v[1] + m[k, 10] * v[2],
    )


@jit_inline
def apply_normal(inv, k, n):
    """Transform normal ``n`` by the inverse transpose (``inv`` is the inverse transform)."""
    return (
        inv[k, 0] * n[0] + inv[k, 4] * n[1] + inv[k, 8] * n[2],
        inv[k, 1] * n[0] + inv[k, 5] * n[1] + inv[k, 9] * n[2],
        inv[k, 2] * n[0] + inv[k, 6] * n[1] + inv[k, 10] * n[2],
    )


def round_trip_bound(matrix: np.ndarray) -> tuple[float, float]:
    """Scalars ``(c1, c0)`` with ``|inv(M x) - x|_i <= c1 |x|_max + c0`` for every axis, where
    both products are computed in float64 (``matrix`` is the 4x4 object -> world transform).

    ``y = M x`` is off by at most gamma(3) (|M| |x| + |t|) per axis; mapping it back adds
    gamma(3) (|inv| |y| + |inv t|) and carries the first error through ``|inv|``. Bounding
    |x| by its largest component turns the matrix products into row sums.
    """
    m = np.abs(matrix[:3, :3])
    t = np.abs(matrix[:3, 3])
    inverse = portable.affine_inverse(matrix)
    n = np.abs(inverse[:3, :3])
    s = np.abs(inverse[:3, 3])
    y_per_x = m[:, 0] + m[:, 1] + m[:, 2]  # |y| <= y_per_x |x| + t
    back_per_x = portable.transform_vectors(y_per_x, n)  # |inv| |y|
    back_const = portable.transform_vectors(t, n) + s
    carried_per_x = portable.transform_vectors(GAMMA3 * y_per_x, n)
    carried_const = portable.transform_vectors(GAMMA3 * t, n)
    c1 = float(np.max(GAMMA3 * back_per_x + (1.0 + GAMMA3) * carried_per_x))
    c0 = float(np.max(GAMMA3 * back_const + (1.0 + GAMMA3) * carried_const))
    return 2.0 * c1, 2.0 * c0  # a factor two covers the rounding of the bound itself

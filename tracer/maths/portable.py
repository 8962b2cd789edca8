"""Arithmetic whose result is the same on every CPU, for what scene compilation derives.

numpy hands matrix products, norms and inverses to BLAS and LAPACK, whose kernels differ per
CPU (FMA or not, the order of a dot product), and evaluates ``tan``, ``exp``, ``log``, ``arccos``
and ``power`` on arrays with SIMD code chosen per CPU. Each gives different last bits on
different machines, and a compiled scene must not: every tracer compiles its own replica and
the pixels must agree bit for bit (``docs/cluster.md``). The helpers here use only elementwise
additions and multiplications in a fixed order (IEEE-exact on every CPU) and the C library's
scalar functions.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np


def dot(a, b) -> float:
    """Left-to-right sum of the products of two short vectors."""
    total = 0.0
    for x, y in zip(
        np.asarray(a, np.float64).ravel(), np.asarray(b, np.float64).ravel(), strict=True
    ):
        total += float(x) * float(y)
    return total


def norm(v) -> float:
    """Euclidean length of a short vector (``math.hypot``: exact to an ulp, CPU-independent)."""
    return math.hypot(*(float(x) for x in np.asarray(v, np.float64).ravel()))


def normalized(v) -> np.ndarray:
    """``v`` over its length (float64)."""
    v = np.asarray(v, np.float64)
    return v / norm(v)


def cross(a, b) -> np.ndarray:
    """Cross product of two 3-vectors."""
    ax, ay, az = (float(x) for x in np.asarray(a, np.float64))
    bx, by, bz = (float(x) for x in np.asarray(b, np.float64))
    return np.array([ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx])


SMALL = 16
"""Matrices of at most this many entries are multiplied in Python floats (the same IEEE
operations in the same order, so the same bits): numpy's per-call overhead is most of the cost
of a 4x4 product, and scene loading and compilation make several per object."""


def matmul(a, b) -> np.ndarray:
    """``a @ b`` for 2-D float arrays (or a stack of them), summed over k in order."""
    a = np.asarray(a, np.float64)
    b = np.asarray(b, np.float64)
    if a.ndim == b.ndim == 2 and 0 < a.shape[1] == b.shape[0] and max(a.size, b.size) <= SMALL:
        return _small_matmul(a.tolist(), b.tolist())
    with np.errstate(over="ignore", invalid="ignore"):
        out = a[..., :, 0:1] * b[..., 0:1, :]
        for k in range(1, a.shape[-1]):
            out = out + a[..., :, k : k + 1] * b[..., k : k + 1, :]
    return out


def _small_matmul(a: list, b: list) -> np.ndarray:
    """``matmul`` of two small matrices given as lists of rows of Python floats."""
    inner = range(1, len(b))
    out = []
    for row in a:
        line = []
        for j in range(len(b[0])):
            total = row[0] * b[0][j]
            for k in inner:
                total = total + row[k] * b[k][j]
            line.append(total)
        out.append(line)
    return np.array(out, np.float64)


def chain(*matrices) -> np.ndarray:
    """The product of square matrices from left to right."""
    out = np.asarray(matrices[0], np.float64)
    for m in matrices[1:]:
        out = matmul(out, m)
    return out


def transform_points(points, matrix) -> np.ndarray:
    """``points @ matrix[:3, :3].T + matrix[:3, 3]`` for (..., 3) points and a 3x4 or 4x4 affine
    matrix."""
    p = np.asarray(points, np.float64)
    m = np.asarray(matrix, np.float64)
    with np.errstate(over="ignore", invalid="ignore"):  # as BLAS: inf and NaN pass through
        out = p[..., 0:1] * m[:3, 0] + p[..., 1:2] * m[:3, 1]
        out = out + p[..., 2:3] * m[:3, 2]
        return out + m[:3, 3]


def transform_vectors(vectors, linear) -> np.ndarray:
    """``vectors @ linear[:3, :3].T`` for (..., 3) vectors."""
    v = np.asarray(vectors, np.float64)
    m = np.asarray(linear, np.float64)
    with np.errstate(over="ignore", invalid="ignore"):
        out = v[..., 0:1] * m[:3, 0] + v[..., 1:2] * m[:3, 1]
        return out + v[..., 2:3] * m[:3, 2]


def det3(m) -> np.ndarray | float:
    """Determinant of the leading 3x3 block of a matrix (or of each in a stack)."""
    m = np.asarray(m, np.float64)
    if m.ndim == 2:  # one matrix: Python floats, the same operations (see ``SMALL``)
        (a, b, c, *_), (d, e, f, *_), (g, h, i, *_) = m[:3].tolist()
        return a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g)
    a, b, c = m[..., 0, 0], m[..., 0, 1], m[..., 0, 2]
    d, e, f = m[..., 1, 0], m[..., 1, 1], m[..., 1, 2]
    g, h, i = m[..., 2, 0], m[..., 2, 1], m[..., 2, 2]
    det = a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g)
    return float(det) if np.ndim(det) == 0 else det


def affine_inverse(matrix) -> np.ndarray:
    """Inverse of a 4x4 affine matrix (bottom row 0 0 0 1) by Gauss-Jordan elimination with
    partial pivoting on its 3x3 block, in Python floats; raises ZeroDivisionError when singular."""
    m = np.asarray(matrix, np.float64)
    rows = [[float(m[r, c]) for c in range(3)] + [1.0 if c == r else 0.0 for c in range(3)]
            for r in range(3)]  # fmt: skip
    for col in range(3):
        pivot = max(range(col, 3), key=lambda r: abs(rows[r][col]))
        if rows[pivot][col] == 0.0:
            raise ZeroDivisionError("the matrix is singular")
        rows[col], rows[pivot] = rows[pivot], rows[col]
        scale = rows[col][col]
        rows[col] = [x / scale for x in rows[col]]
        for r in range(3):
            if r != col and rows[r][col] != 0.0:
                factor = rows[r][col]
                rows[r] = [x - factor * y for x, y in zip(rows[r], rows[col], strict=True)]
    inverse = np.eye(4)
    inverse[:3, :3] = [row[3:] for row in rows]
    inverse[:3, 3] = -transform_vectors(m[:3, 3], inverse)
    return inverse


def elementwise(function: Callable[[float], float], values) -> np.ndarray:
    """``function`` (a scalar C-library function such as ``math.tan``) applied to every element."""
    values = np.asarray(values, np.float64)
    flat = [function(float(x)) for x in values.ravel()]
    return np.array(flat, np.float64).reshape(values.shape)

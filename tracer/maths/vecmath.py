"""Small vector helpers on 3-tuples of float64, for use inside kernels.

Tuples live in registers in numba, so these compile to plain scalar code with no allocation.
"""

import math

from tracer.kernel.jit import jit


@jit
def add(a, b):
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2])


@jit
def sub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


@jit
def scale(a, s):
    return (a[0] * s, a[1] * s, a[2] * s)


@jit
def mul(a, b):
    """Component-wise product."""
    return (a[0] * b[0], a[1] * b[1], a[2] * b[2])


@jit
def dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@jit
def cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


@jit
def length(a):
    return math.sqrt(dot(a, a))


@jit
def max_component(a):
    return max(a[0], max(a[1], a[2]))


@jit
def coordinate_system(n):
    """Two unit vectors completing unit ``n`` to an orthonormal basis (Duff et al. 2017)."""
    sign = math.copysign(1.0, n[2])
    a = -1.0 / (sign + n[2])
    b = n[0] * n[1] * a
    s = (1.0 + sign * n[0] * n[0] * a, sign * b, -sign * n[0])
    t = (b, sign + n[1] * n[1] * a, -n[1])
    return s, t


@jit
def to_world(local, s, t, n):
    """Map ``local`` from the frame (s, t, n) to world space."""
    return (
        s[0] * local[0] + t[0] * local[1] + n[0] * local[2],
        s[1] * local[0] + t[1] * local[1] + n[1] * local[2],
        s[2] * local[0] + t[2] * local[1] + n[2] * local[2],
    )

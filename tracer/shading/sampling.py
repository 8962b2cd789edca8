"""Warps from the unit square, each with its pdf (named in threes, after Mitsuba's warp module)."""

import math

from tracer.kernel.jit import jit
from tracer.maths.vecmath import coordinate_system, to_world

INV_PI = 1.0 / math.pi


@jit
def square_to_uniform_disk_concentric(u1, u2):
    """Shirley-Chiu concentric map of [0,1)^2 onto the unit disk."""
    x = 2.0 * u1 - 1.0
    y = 2.0 * u2 - 1.0
    if x == 0.0 and y == 0.0:
        return 0.0, 0.0
    if abs(x) > abs(y):
        r = x
        phi = (math.pi / 4.0) * (y / x)
    else:
        r = y
        phi = (math.pi / 2.0) - (math.pi / 4.0) * (x / y)
    return r * math.cos(phi), r * math.sin(phi)


@jit
def square_to_cosine_hemisphere(u1, u2):
    """Cosine-weighted direction about +z (Malley's method)."""
    x, y = square_to_uniform_disk_concentric(u1, u2)
    z = math.sqrt(max(0.0, 1.0 - x * x - y * y))
    return (x, y, z)


@jit
def square_to_cosine_hemisphere_pdf(cos_theta):
    """Solid-angle density of :func:`square_to_cosine_hemisphere` for this cosine."""
    return cos_theta * INV_PI if cos_theta > 0.0 else 0.0


@jit
def square_to_uniform_triangle(u1, u2):
    """Barycentrics (b0, b1, b2) uniformly distributed over a triangle."""
    su = math.sqrt(u1)
    b0 = 1.0 - su
    b1 = u2 * su
    return b0, b1, 1.0 - b0 - b1


@jit
def power_heuristic(pa, pb):
    """MIS weight of strategy a against strategy b (Veach's power heuristic, beta = 2)."""
    a2 = pa * pa
    b2 = pb * pb
    total = a2 + b2
    return a2 / total if total > 0.0 else 0.0


@jit
def square_to_uniform_sphere(u1, u2):
    """Uniformly distributed unit vector."""
    z = 1.0 - 2.0 * u1
    r = math.sqrt(max(0.0, 1.0 - z * z))
    phi = 2.0 * math.pi * u2
    return (r * math.cos(phi), r * math.sin(phi), z)


@jit
def square_to_uniform_cone(u1, u2, one_minus_cos_max, axis):
    """Unit vector uniformly distributed in the cone of half-angle theta_max about the unit
    ``axis``, given ``1 - cos(theta_max)`` (kept apart to avoid cancellation for small cones)."""
    a = u1 * one_minus_cos_max
    cos_t = 1.0 - a
    sin_t = math.sqrt(max(0.0, a * (2.0 - a)))
    phi = 2.0 * math.pi * u2
    local = (sin_t * math.cos(phi), sin_t * math.sin(phi), cos_t)
    s, t = coordinate_system(axis)
    return to_world(local, s, t, axis)

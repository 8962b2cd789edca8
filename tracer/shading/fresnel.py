"""Fresnel reflectance of dielectric and conductor boundaries, and refraction (Snell's law).

Conventions follow pbrt-v4 (``FrDielectric``, ``FrComplex``, ``Refract``): ``cos_i`` is the
cosine between the incident direction and the normal on the incident side, and ``eta`` is the
*relative* index of refraction, transmitted side over incident side.
"""

import math

from tracer.kernel.jit import jit


@jit
def fr_dielectric(cos_i, eta):
    """Unpolarised Fresnel reflectance of a smooth dielectric boundary; 1 under total internal
    reflection. ``cos_i`` in [0, 1] on the incident side, ``eta`` = eta_t / eta_i."""
    cos_i = min(1.0, max(0.0, cos_i))
    sin2_t = (1.0 - cos_i * cos_i) / (eta * eta)
    if sin2_t >= 1.0:
        return 1.0
    cos_t = math.sqrt(1.0 - sin2_t)
    r_parl = (eta * cos_i - cos_t) / (eta * cos_i + cos_t)
    r_perp = (cos_i - eta * cos_t) / (cos_i + eta * cos_t)
    return 0.5 * (r_parl * r_parl + r_perp * r_perp)


@jit
def fr_conductor(cos_i, eta, k):
    """Unpolarised Fresnel reflectance of a conductor with complex index ``eta + i k`` (one
    channel), seen from a medium of index 1: pbrt-v3's ``FrConductor`` in real arithmetic."""
    cos_i = min(1.0, max(0.0, cos_i))
    cos2 = cos_i * cos_i
    sin2 = 1.0 - cos2
    eta2 = eta * eta
    k2 = k * k
    t0 = eta2 - k2 - sin2
    a2_plus_b2 = math.sqrt(t0 * t0 + 4.0 * eta2 * k2)
    t1 = a2_plus_b2 + cos2
    a = math.sqrt(max(0.0, 0.5 * (a2_plus_b2 + t0)))
    t2 = 2.0 * cos_i * a
    rs = (t1 - t2) / (t1 + t2)
    t3 = cos2 * a2_plus_b2 + sin2 * sin2
    t4 = t2 * sin2
    rp = rs * (t3 - t4) / (t3 + t4)
    return 0.5 * (rp + rs)


@jit
def refract_local(wo, eta):
    """Direction transmitted through a boundary with normal +z for ``wo`` (z > 0, unit) and
    relative index ``eta``; ``(wi, ok)`` with ok False under total internal reflection."""
    sin2_t = (1.0 - wo[2] * wo[2]) / (eta * eta)
    if sin2_t >= 1.0:
        return (0.0, 0.0, 0.0), False
    cos_t = math.sqrt(1.0 - sin2_t)
    return (-wo[0] / eta, -wo[1] / eta, -cos_t), True

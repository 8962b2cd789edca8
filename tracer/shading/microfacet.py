"""The isotropic GGX (Trowbridge-Reitz) microfacet distribution, its visible normals, and the
directional albedos of a rough dielectric interface (the plastic coat's tables).

Directions are in the local shading frame (the macro normal is +z), unit length. ``alpha`` is
GGX's roughness parameter (the scene format's ``roughness`` squared). Masking-shadowing is
Smith's height-correlated form ``G = 1 / (1 + Lambda(wo) + Lambda(wi))`` (pbrt-v4, section
9.6). Visible normals are sampled with Heitz's method ("Sampling the GGX Distribution of
Visible Normals", JCGT 7(4), 2018), whose density is ``G1(wo) max(0, wo.m) D(m) / wo.z``.
"""

import math

from tracer.kernel.jit import jit
from tracer.shading.fresnel import fr_dielectric


@jit
def ggx_d(m, alpha):
    """Microfacet normal density ``D(m)`` (per unit projected solid angle of the macro surface)."""
    cos2 = m[2] * m[2]
    if m[2] <= 0.0:
        return 0.0
    a2 = alpha * alpha
    den = cos2 * (a2 - 1.0) + 1.0
    return a2 / (math.pi * den * den)


@jit
def ggx_lambda(w, alpha):
    """Smith's auxiliary function Lambda(w) for GGX."""
    cos2 = w[2] * w[2]
    if cos2 == 0.0:
        return math.inf
    sin2 = max(0.0, w[0] * w[0] + w[1] * w[1])
    return 0.5 * (math.sqrt(1.0 + alpha * alpha * sin2 / cos2) - 1.0)


@jit
def ggx_g1(w, alpha):
    """Masking of direction ``w``."""
    return 1.0 / (1.0 + ggx_lambda(w, alpha))


@jit
def ggx_g(wo, wi, alpha):
    """Height-correlated masking-shadowing of the pair."""
    return 1.0 / (1.0 + ggx_lambda(wo, alpha) + ggx_lambda(wi, alpha))


@jit
def ggx_sample_visible_normal(wo, alpha, u1, u2):
    """A microfacet normal ``m`` distributed as the normals visible from ``wo`` (wo.z > 0)."""
    # Stretch the view direction to the hemisphere configuration (alpha = 1).
    vx = alpha * wo[0]
    vy = alpha * wo[1]
    vz = wo[2]
    inv = 1.0 / math.sqrt(vx * vx + vy * vy + vz * vz)
    vx *= inv
    vy *= inv
    vz *= inv
    # An orthonormal basis (with special case when the view is the pole).
    lensq = vx * vx + vy * vy
    if lensq > 0.0:
        inv_len = 1.0 / math.sqrt(lensq)
        t1 = (-vy * inv_len, vx * inv_len, 0.0)
    else:
        t1 = (1.0, 0.0, 0.0)
    t2 = (vy * t1[2] - vz * t1[1], vz * t1[0] - vx * t1[2], vx * t1[1] - vy * t1[0])
    # A point on the projected half disc.
    r = math.sqrt(u1)
    phi = 2.0 * math.pi * u2
    p1 = r * math.cos(phi)
    p2 = r * math.sin(phi)
    s = 0.5 * (1.0 + vz)
    p2 = (1.0 - s) * math.sqrt(max(0.0, 1.0 - p1 * p1)) + s * p2
    # Reproject onto the hemisphere, then unstretch.
    p3 = math.sqrt(max(0.0, 1.0 - p1 * p1 - p2 * p2))
    nx = p1 * t1[0] + p2 * t2[0] + p3 * vx
    ny = p1 * t1[1] + p2 * t2[1] + p3 * vy
    nz = p1 * t1[2] + p2 * t2[2] + p3 * vz
    mx = alpha * nx
    my = alpha * ny
    mz = max(1e-12, nz)
    inv = 1.0 / math.sqrt(mx * mx + my * my + mz * mz)
    return (mx * inv, my * inv, mz * inv)


@jit
def ggx_visible_normal_pdf(wo, m, alpha):
    """Density of :func:`ggx_sample_visible_normal` (per unit solid angle of ``m``)."""
    dot_om = wo[0] * m[0] + wo[1] * m[1] + wo[2] * m[2]
    if dot_om <= 0.0 or wo[2] <= 0.0:
        return 0.0
    return ggx_g1(wo, alpha) * dot_om * ggx_d(m, alpha) / wo[2]


@jit
def reflect_local(wo, m):
    """``wo`` mirrored about the unit vector ``m``."""
    c = 2.0 * (wo[0] * m[0] + wo[1] * m[1] + wo[2] * m[2])
    return (c * m[0] - wo[0], c * m[1] - wo[1], c * m[2] - wo[2])


@jit
def half_vector(wo, wi):
    """The unit half vector of a reflected pair (both above the surface)."""
    hx = wo[0] + wi[0]
    hy = wo[1] + wi[1]
    hz = wo[2] + wi[2]
    length = math.sqrt(hx * hx + hy * hy + hz * hz)
    if length == 0.0:
        return (0.0, 0.0, 0.0)
    inv = 1.0 / length
    return (hx * inv, hy * inv, hz * inv)


@jit
def ggx_reflection_pdf(wo, wi, alpha):
    """Solid-angle density of ``wi`` when a visible normal is sampled and ``wo`` reflected
    about it: ``G1(wo) D(h) / (4 wo.z)``."""
    if wo[2] <= 0.0 or wi[2] <= 0.0:
        return 0.0
    h = half_vector(wo, wi)
    return ggx_g1(wo, alpha) * ggx_d(h, alpha) / (4.0 * wo[2])


@jit
def ggx_dielectric_albedo(cos_theta, alpha, eta, nodes, weights):
    """Single-scattering directional albedo ``(R, T)`` of a GGX dielectric interface: the
    shares of light arriving at ``cos_theta`` (> 0) from the side where the relative index is
    ``eta`` that it reflects and transmits (after masking-shadowing, both height-correlated).

    Each is the integral over visible normals ``m`` of Fresnel times ``G(wi, w) / G1(wi)``, ``w``
    the reflected or refracted direction: a product rule over the unit square of Heitz's
    sampler, ``nodes`` and ``weights`` (summing to 1) per axis.
    """
    wi = (math.sqrt(max(0.0, 1.0 - cos_theta * cos_theta)), 0.0, cos_theta)
    lambda_i = ggx_lambda(wi, alpha)
    r = 0.0
    t = 0.0
    for a in range(nodes.shape[0]):
        for b in range(nodes.shape[0]):
            m = ggx_sample_visible_normal(wi, alpha, nodes[a], nodes[b])
            w = weights[a] * weights[b] * (1.0 + lambda_i)  # / G1(wi)
            cos_im = wi[0] * m[0] + wi[1] * m[1] + wi[2] * m[2]
            f = fr_dielectric(cos_im, eta)
            wr = reflect_local(wi, m)
            if wr[2] > 0.0:
                r += w * f / (1.0 + lambda_i + ggx_lambda(wr, alpha))
            sin2_t = (1.0 - cos_im * cos_im) / (eta * eta)
            if sin2_t < 1.0:
                c = cos_im / eta - math.sqrt(1.0 - sin2_t)
                wt = (c * m[0] - wi[0] / eta, c * m[1] - wi[1] / eta, c * m[2] - wi[2] / eta)
                if wt[2] < 0.0:
                    t += w * (1.0 - f) / (1.0 + lambda_i + ggx_lambda(wt, alpha))
    return r, t

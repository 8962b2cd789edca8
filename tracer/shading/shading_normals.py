"""What shading with interpolated normals needs beyond the BSDFs: the normal bent so a mirror
reflection stays above the surface, and the shadow terminator's smooth falloff.

Every BSDF is evaluated about the shading normal ``ns``; the geometric normal ``n`` (turned
toward the viewer, like ``ns``) still decides sidedness, which side a ray leaves from, and
whether a direction counts as reflection or transmission (``geometric_side``), so light never
leaks through a surface whose shading normal leans over its geometric one.

- **Bending** (Keller et al., "The Iray Light Transport Simulation and Rendering System",
  2017; Houdini's *Normal Clamp*): where the mirror reflection of ``wo`` about ``ns`` would
  point below the geometric surface (always the case when ``wo`` is below the shading
  hemisphere, the cause of black fringes), ``ns`` becomes the half vector between ``wo`` and
  that reflection lifted to ``BEND_LIFT`` above the tangent plane.
- **Terminator** (Chiang, Li and Burley, "Taming the Shadow Terminator", SIGGRAPH 2019 talk):
  reflected light is scaled by ``-G^3 + G^2 + G`` with
  ``G = min(1, (n . wi) / ((ns . wi)(ns . n)))``, which fades it out smoothly where the
  geometric surface, not the shading one, would have turned away from the light.
"""

import math

from tracer.kernel.jit import jit_inline

BEND_LIFT = 0.01
"""Cosine with the geometric normal of a mirror reflection that bending raises (it was lower)."""


@jit_inline
def bent_normal(ns, n, wo):
    """``ns`` (unit, on ``n``'s side) bent toward ``n`` just enough that ``wo``'s mirror
    reflection about it lies ``BEND_LIFT`` above the surface; ``ns`` itself if it already does."""
    c = 2.0 * (wo[0] * ns[0] + wo[1] * ns[1] + wo[2] * ns[2])
    r = (c * ns[0] - wo[0], c * ns[1] - wo[1], c * ns[2] - wo[2])
    r_n = r[0] * n[0] + r[1] * n[1] + r[2] * n[2]
    if r_n >= BEND_LIFT:
        return ns
    # r on the tangent plane (its part along n removed), scaled to leave BEND_LIFT along n.
    t = (r[0] - r_n * n[0], r[1] - r_n * n[1], r[2] - r_n * n[2])
    t_len = math.sqrt(t[0] * t[0] + t[1] * t[1] + t[2] * t[2])
    if t_len > 0.0:
        k = math.sqrt(1.0 - BEND_LIFT * BEND_LIFT) / t_len
        r = (t[0] * k + BEND_LIFT * n[0], t[1] * k + BEND_LIFT * n[1], t[2] * k + BEND_LIFT * n[2])
    else:
        r = n
    h = (wo[0] + r[0], wo[1] + r[1], wo[2] + r[2])
    h_len = math.sqrt(h[0] * h[0] + h[1] * h[1] + h[2] * h[2])
    if not h_len > 0.0:
        return n
    return (h[0] / h_len, h[1] / h_len, h[2] / h_len)


@jit_inline
def terminator(ns, n, wi):
    """Chiang et al.'s shadowing factor in [0, 1] for light reflected from ``wi`` (above the
    geometric surface ``n``); 1 where shading and geometric normals agree."""
    cos_s = ns[0] * wi[0] + ns[1] * wi[1] + ns[2] * wi[2]
    cos_sn = ns[0] * n[0] + ns[1] * n[1] + ns[2] * n[2]
    denominator = cos_s * cos_sn
    if not denominator > 0.0:
        return 0.0
    g = min(1.0, (n[0] * wi[0] + n[1] * wi[1] + n[2] * wi[2]) / denominator)
    if g <= 0.0:
        return 0.0
    return g * (1.0 + g * (1.0 - g))


@jit_inline
def geometric_side(n, wo, wi):
    """1 if ``wi`` leaves the geometric surface on ``wo``'s side (reflection), -1 on the other
    (transmission), 0 on the tangent plane."""
    c = (n[0] * wi[0] + n[1] * wi[1] + n[2] * wi[2]) * (n[0] * wo[0] + n[1] * wo[1] + n[2] * wo[2])
    return 1 if c > 0.0 else (-1 if c < 0.0 else 0)

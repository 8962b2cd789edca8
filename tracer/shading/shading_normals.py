"""What shading with interpolated normals needs beyond the BSDFs: the normal bent where the
viewer falls below it, and the shadow terminator's smooth falloff.

Every BSDF is evaluated about the shading normal ``ns``; the geometric normal ``n`` (turned
toward the viewer, like ``ns``) still decides sidedness, which side a ray leaves from, and
whether a direction counts as reflection or transmission (``geometric_side``), so light never
leaks through a surface whose shading normal leans over its geometric one.

- **Bending**: where ``wo`` falls below the shading hemisphere (``wo . ns < 0``, the cause of
  black fringes), ``ns`` is turned toward ``wo`` in their common plane until
  ``wo . ns = BEND_COSINE``: the smallest change that fixes it. Keller et al. ("The Iray Light
  Transport Simulation and Rendering System", 2017) and Houdini's *Normal Clamp* bend further,
  until ``wo``'s mirror reflection is above the surface; we do not, so wherever Mitsuba and
  pbrt (which do not bend) shade a point, we shade it as they do.
- **Terminator** (Chiang, Li and Burley, "Taming the Shadow Terminator", SIGGRAPH 2019 talk):
  reflected light is scaled by ``-G^3 + G^2 + G`` with
  ``G = min(1, (n . wi) / ((ns . wi)(ns . n)))``, which fades it out smoothly where the
  geometric surface, not the shading one, would have turned away from the light.
"""

import math

from tracer.kernel.jit import jit_inline

BEND_COSINE = 0.01
"""The cosine between ``wo`` and a shading normal that bending leaves (it was lower)."""


@jit_inline
def bent_normal(ns, n, wo):
    """``ns`` (unit, on ``n``'s side) turned toward ``wo`` just enough that ``wo . ns`` is
    ``BEND_COSINE``, where it was less; ``ns`` itself otherwise."""
    a = wo[0] * ns[0] + wo[1] * ns[1] + wo[2] * ns[2]
    if a >= BEND_COSINE:
        return ns
    # The part of ns across wo, then the unit vector in their plane at BEND_COSINE to wo.
    p = (ns[0] - a * wo[0], ns[1] - a * wo[1], ns[2] - a * wo[2])
    p_len = math.sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2])
    if not p_len > 0.0:
        return n
    k = math.sqrt(1.0 - BEND_COSINE * BEND_COSINE) / p_len
    return (BEND_COSINE * wo[0] + k * p[0], BEND_COSINE * wo[1] + k * p[1],
            BEND_COSINE * wo[2] + k * p[2])  # fmt: skip


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

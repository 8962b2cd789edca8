"""Scene-format materials -> the columns of the material table kernels read.

One row per material: its kind (``tracer.shading.bsdf`` constants), reflectance colour, emitted
radiance, sidedness and a row of ``bsdf.PARAM_COLUMNS`` float64 parameters. The conversions that
are not plain copies are here: roughness to GGX alpha, a conductor's reflectance to a complex index
of refraction, a plastic coat's transmittance table and internal diffuse reflectance (quadratures
of the rough interface). docs/materials.md states every formula.
"""

import functools
import math
from typing import NamedTuple

import numpy as np

from tracer.scene import format as fmt
from tracer.shading import bsdf

DEFAULT_CONDUCTOR_REFLECTANCE = (0.9, 0.9, 0.9)
MAX_CONDUCTOR_REFLECTANCE = 0.9999
"""Normal-incidence reflectance is clamped below 1, where the fitted index diverges."""
PLASTIC_MIN_ALPHA = 1e-3
"""A plastic coat's GGX alpha is at least this (its specular lobe is never a delta)."""
COAT_QUADRATURE = 64
"""Gauss-Legendre nodes per axis of the product rule over a coat's visible normals."""
COAT_CRITICAL_QUADRATURE = 32
"""Gauss-Legendre nodes in cos(theta) on each side of the coat's critical angle, for its
internal diffuse reflectance."""


class MaterialTable(NamedTuple):
    """Per material, in the state's order: ``kind`` int32 (K,), ``albedo`` and ``emission``
    float32 (K, 3), ``two_sided`` bool (K,), ``param`` float64 (K, ``bsdf.PARAM_COLUMNS``).

    ``albedo`` is the base colour a texture multiplies: the reflectance of diffuse, mirror and
    plastic materials; white for conductors (their colour is in ``eta`` and ``k``, and a
    texture tints their Fresnel term) and dielectrics."""

    kind: np.ndarray
    albedo: np.ndarray
    emission: np.ndarray
    two_sided: np.ndarray
    param: np.ndarray


def roughness_to_alpha(roughness: float) -> float:
    """GGX alpha from the perceptual roughness of the scene format (and glTF): its square."""
    return float(roughness) ** 2


def conductor_index_from_reflectance(r: float) -> tuple[float, float]:
    """A complex index ``(eta, k)`` whose Fresnel reflectance at normal incidence is ``r``, with
    a white edge tint: Gulbrandsen's artist-friendly mapping (JCGT 3(4), 2014) at g = 1, where
    ``eta = (1 - r) / (1 + r)`` and ``k^2 = (r (eta + 1)^2 - (eta - 1)^2) / (1 - r)``."""
    r = min(max(float(r), 0.0), MAX_CONDUCTOR_REFLECTANCE)
    eta = (1.0 - r) / (1.0 + r)
    k2 = (r * (eta + 1.0) ** 2 - (eta - 1.0) ** 2) / (1.0 - r)
    return eta, math.sqrt(max(0.0, k2))


def gauss_legendre(n: int, lo: float = 0.0, hi: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Nodes and weights of the ``n``-point Gauss-Legendre rule on ``[lo, hi]``."""
    x, w = np.polynomial.legendre.leggauss(n)
    half = 0.5 * (hi - lo)
    return lo + half * (x + 1.0), half * w


@functools.lru_cache(maxsize=256)
def coat_tables(alpha: float, ior: float) -> tuple[tuple[float, ...], float]:
    """A rough plastic coat's tables, as Mitsuba 3's ``roughplastic`` precomputes them (with
    our height-correlated masking and accurate quadratures).

    Returns the transmittance correction at ``cos = j / (bsdf.COAT_NODES - 1)``: the coat's
    single-scattering transmittance ``T(cos)`` from outside (``microfacet.
    ggx_dielectric_albedo``; the first node at cos 1e-6) minus the smooth interface's ``1 -
    F(cos)``; and its internal diffuse reflectance ``2 * integral_0^1 R(mu, 1/ior) mu dmu``,
    ``R`` the coat's directional reflectance from inside, by Gauss-Legendre on each side of
    the critical cosine (where total internal reflection begins).
    """
    from tracer.shading.fresnel import fr_dielectric
    from tracer.shading.microfacet import ggx_dielectric_albedo

    nodes, weights = gauss_legendre(COAT_QUADRATURE)
    mu = np.linspace(0.0, 1.0, bsdf.COAT_NODES)
    correction = tuple(
        ggx_dielectric_albedo(max(m, 1e-6), alpha, ior, nodes, weights)[1]
        - (1.0 - fr_dielectric.py_func(float(m), ior))
        for m in mu
    )
    critical = math.sqrt(1.0 - 1.0 / (ior * ior))
    fdr = 0.0
    for lo, hi in ((0.0, critical), (critical, 1.0)):
        for m, w in zip(*gauss_legendre(COAT_CRITICAL_QUADRATURE, lo, hi), strict=True):
            r = ggx_dielectric_albedo(m, alpha, 1.0 / ior, nodes, weights)[0]
            fdr += 2.0 * w * r * m
    return correction, fdr


def material_row(m: fmt.Material) -> tuple[int, tuple, tuple, bool, np.ndarray]:
    """``(kind, albedo, emission, two_sided, param)`` of one material."""
    param = np.zeros(bsdf.PARAM_COLUMNS)
    kind = bsdf.MATERIAL_KINDS[m.type]
    if isinstance(m, fmt.DielectricMaterial):
        param[bsdf.IOR] = m.ior
        param[bsdf.SIGMA : bsdf.SIGMA + 3] = m.absorption
        return kind, (1.0, 1.0, 1.0), (0.0, 0.0, 0.0), True, param
    if isinstance(m, fmt.ConductorMaterial):
        param[bsdf.ALPHA] = roughness_to_alpha(m.roughness)
        if m.eta is not None:
            eta, k = m.eta, m.k
        else:
            reflectance = m.reflectance or DEFAULT_CONDUCTOR_REFLECTANCE
            eta, k = zip(*(conductor_index_from_reflectance(r) for r in reflectance), strict=True)
        param[bsdf.ETA : bsdf.ETA + 3] = eta
        param[bsdf.K : bsdf.K + 3] = k
        return kind, (1.0, 1.0, 1.0), m.emission, m.two_sided, param
    if isinstance(m, fmt.PlasticMaterial):
        alpha = max(PLASTIC_MIN_ALPHA, roughness_to_alpha(m.roughness))
        correction, fdr = coat_tables(alpha, float(m.ior))
        param[bsdf.ALPHA] = alpha
        param[bsdf.IOR] = m.ior
        param[bsdf.FDR_INT] = fdr
        param[bsdf.COAT_TABLE : bsdf.COAT_TABLE + bsdf.COAT_NODES] = correction
        d_mean = sum(m.reflectance) / 3.0
        param[bsdf.SPECULAR_WEIGHT] = 1.0 / (1.0 + d_mean)
        return kind, m.reflectance, m.emission, m.two_sided, param
    return kind, m.reflectance, m.emission, m.two_sided, param


def material_table(materials: list[fmt.Material]) -> MaterialTable:
    """Columns of the material models, in their order."""
    rows = [material_row(m) for m in materials]
    return MaterialTable(
        kind=np.array([r[0] for r in rows], dtype=np.int32),
        albedo=np.array([r[1] for r in rows], dtype=np.float32).reshape(-1, 3),
        emission=np.array([r[2] for r in rows], dtype=np.float32).reshape(-1, 3),
        two_sided=np.array([r[3] for r in rows], dtype=np.bool_),
        param=np.array([r[4] for r in rows], dtype=np.float64).reshape(-1, bsdf.PARAM_COLUMNS),
    )

"""Scene-format materials -> the columns of the material table kernels read.

One row per material: its kind (``tracer.bsdf`` constants), reflectance colour, emitted radiance,
sidedness and a row of ``bsdf.PARAMS`` float64 parameters. The conversions that are not plain
copies are here: roughness to GGX alpha, a conductor's reflectance to a complex index of
refraction, a plastic coat's internal diffuse Fresnel reflectance. docs/materials.md states
every formula.
"""

import math
from typing import NamedTuple

import numpy as np

from tracer import bsdf
from tracer import scene_format as fmt

DEFAULT_CONDUCTOR_REFLECTANCE = (0.9, 0.9, 0.9)
MAX_CONDUCTOR_REFLECTANCE = 0.9999
"""Normal-incidence reflectance is clamped below 1, where the fitted index diverges."""
PLASTIC_MIN_ALPHA = 1e-3
"""A plastic coat's GGX alpha is at least this (its specular lobe is never a delta)."""


class MaterialTable(NamedTuple):
    """Per material, in the state's order: ``kind`` int32 (K,), ``albedo`` and ``emission``
    float32 (K, 3), ``two_sided`` bool (K,), ``param`` float64 (K, ``bsdf.PARAMS``).

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


def fresnel_diffuse_reflectance(eta: float, steps: int = 4096) -> float:
    """Cosine-weighted hemispherical average of the dielectric Fresnel reflectance seen from the
    side where the relative index is ``eta``: ``2 * integral_0^1 F(mu, eta) mu dmu`` (midpoint
    rule)."""
    from tracer.fresnel import fr_dielectric

    mu = (np.arange(steps) + 0.5) / steps
    f = np.array([fr_dielectric.py_func(float(m), eta) for m in mu])
    return float(2.0 * np.sum(f * mu) / steps)


def material_row(m: fmt.Material) -> tuple[int, tuple, tuple, bool, np.ndarray]:
    """``(kind, albedo, emission, two_sided, param)`` of one material."""
    param = np.zeros(bsdf.PARAMS)
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
        param[bsdf.ALPHA] = max(PLASTIC_MIN_ALPHA, roughness_to_alpha(m.roughness))
        param[bsdf.IOR] = m.ior
        param[bsdf.FDR_INT] = fresnel_diffuse_reflectance(1.0 / m.ior)
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
        param=np.array([r[4] for r in rows], dtype=np.float64).reshape(-1, bsdf.PARAMS),
    )

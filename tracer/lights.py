"""Emissive triangles as lights: a power-proportional selection table and area sampling.

A triangle is picked with probability proportional to its emitted power (mean emitted radiance
times area), then a point on it uniformly by area. ``emitter_pdf`` gives the same density for a
point found by a BSDF-sampled ray, which MIS needs.
"""

from typing import NamedTuple

import numpy as np

from tracer.intersect import geometric_normal, hit_point
from tracer.jit import jit, jit_inline
from tracer.sampling import square_to_uniform_triangle


class LightTable(NamedTuple):
    """``tri`` int32 (L,): emissive triangles in leaf order; ``cdf`` float64 (L,): selection CDF,
    last entry exactly 1; ``total_power`` float64 (1,): sum of the selection weights."""

    tri: np.ndarray
    cdf: np.ndarray
    total_power: np.ndarray


@jit_inline
def emission_mean(mat_emission, mat):
    """Mean of a material's emitted RGB radiance: its weight for light selection."""
    return (
        np.float64(mat_emission[mat, 0])
        + np.float64(mat_emission[mat, 1])
        + np.float64(mat_emission[mat, 2])
    ) / 3.0


@jit
def _selection_weights(tri_verts, tri_material, mat_emission):
    m = tri_verts.shape[0]
    weights = np.zeros(m, np.float64)
    for j in range(m):
        mean = emission_mean(mat_emission, tri_material[j])
        if mean > 0.0:
            _, area = geometric_normal(tri_verts, j)
            weights[j] = mean * area
    return weights


def build_light_table(
    tri_verts: np.ndarray, tri_material: np.ndarray, mat_emission: np.ndarray
) -> LightTable:
    """Selection table over every triangle whose material emits."""
    weights = _selection_weights(tri_verts, tri_material, mat_emission)
    tri = np.flatnonzero(weights > 0.0).astype(np.int32)
    total = float(weights[tri].sum())
    cdf = np.cumsum(weights[tri]) / total if tri.size else np.zeros(0)
    if tri.size:
        cdf[-1] = 1.0
    return LightTable(tri, cdf.astype(np.float64), np.array([total]))


@jit_inline
def sample_emitter(light_tri, light_cdf, light_total, tri_verts, tri_material, mat_emission, u):
    """Pick an emissive triangle and a point on it.

    ``u`` is a 3-tuple of uniforms. Returns ``(j, q, q_err, n_l, area, p_select)``: the triangle
    (leaf order), the point and its error bound, the triangle's unit normal and area, and the
    probability of having picked this triangle.
    """
    k = np.searchsorted(light_cdf, u[0], side="right")
    if k >= light_tri.shape[0]:
        k = light_tri.shape[0] - 1
    j = light_tri[k]
    b0, b1, b2 = square_to_uniform_triangle(u[1], u[2])
    q, q_err = hit_point(tri_verts, j, b0, b1, b2)
    n_l, area = geometric_normal(tri_verts, j)
    p_select = emission_mean(mat_emission, tri_material[j]) * area / light_total[0]
    return j, q, q_err, n_l, area, p_select

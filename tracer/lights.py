"""Emissive triangles as lights: a power-proportional selection table and area sampling.

A triangle is picked with probability proportional to its emitted power (mean emitted radiance
times its world-space area), then a point on it uniformly by area (uniform barycentrics stay
uniform under an affine transform). Entries are ordered by (instance, triangle index), never by
BVH leaf order, so refitted and rebuilt meshes sample the same lights with the same numbers.
"""

from typing import NamedTuple

import numpy as np

from tracer.intersect import geometric_normal, hit_point
from tracer.jit import jit_inline
from tracer.sampling import square_to_uniform_triangle
from tracer.scene_arrays import pick
from tracer.scene_intersect import material_of
from tracer.transforms import apply_normal, apply_point


class LightTable(NamedTuple):
    """``inst`` and ``tri`` int32 (L,): each emissive triangle's instance and row in that
    instance's pool; ``cdf`` float64 (L,): selection CDF (last entry exactly 1); ``total_power``
    float64 (1,): the sum of the selection weights."""

    inst: np.ndarray
    tri: np.ndarray
    cdf: np.ndarray
    total_power: np.ndarray


def emission_means(emission: np.ndarray) -> np.ndarray:
    """Selection weight per unit area of each material: the mean of its emitted RGB radiance,
    summed in the same order as the kernels' ``emission_mean``."""
    e = emission.astype(np.float64)
    return (e[:, 0] + e[:, 1] + e[:, 2]) / 3.0


def world_areas(tri_verts: np.ndarray, rows: np.ndarray, xform: np.ndarray) -> np.ndarray:
    """World-space areas of triangles ``rows`` under the 12-value transform ``xform``."""
    v = tri_verts[rows].astype(np.float64).reshape(-1, 3, 3)
    linear = xform.reshape(3, 4)[:, :3]
    e1 = (v[:, 1] - v[:, 0]) @ linear.T
    e2 = (v[:, 2] - v[:, 0]) @ linear.T
    return 0.5 * np.linalg.norm(np.cross(e1, e2), axis=1)


def build_light_table(
    instances: list[tuple[int, np.ndarray, np.ndarray, np.ndarray, np.ndarray]],
    mat_emission: np.ndarray,
) -> LightTable:
    """Selection table over every emissive triangle of every instance.

    ``instances`` lists, in instance order, ``(k, tri_verts, rows, prims, materials, xform)``
    where ``rows``/``prims``/``materials`` describe the instance's triangles (its pool rows,
    their mesh-local indices and material indices).
    """
    weight_per_area = emission_means(mat_emission)
    inst_parts, tri_parts, weight_parts = [], [], []
    for k, tri_verts, rows, prims, materials, xform in instances:
        emits = weight_per_area[materials] > 0.0
        if not emits.any():
            continue
        order = np.argsort(prims[emits], kind="stable")
        chosen = rows[emits][order]
        weights = weight_per_area[materials[emits][order]] * world_areas(tri_verts, chosen, xform)
        inst_parts.append(np.full(chosen.shape[0], k, dtype=np.int32))
        tri_parts.append(chosen.astype(np.int32))
        weight_parts.append(weights)
    if not inst_parts:
        empty = np.zeros(0, np.int32)
        return LightTable(empty, empty.copy(), np.zeros(0), np.zeros(1))
    weights = np.concatenate(weight_parts)
    keep = weights > 0.0
    total = float(weights[keep].sum())
    cdf = np.cumsum(weights[keep]) / total
    cdf[-1] = 1.0
    return LightTable(
        np.concatenate(inst_parts)[keep],
        np.concatenate(tri_parts)[keep],
        cdf,
        np.array([total]),
    )


@jit_inline
def emission_mean(mat_emission, mat):
    """Mean of a material's emitted RGB radiance: its selection weight per unit area."""
    return (
        np.float64(mat_emission[mat, 0])
        + np.float64(mat_emission[mat, 1])
        + np.float64(mat_emission[mat, 2])
    ) / 3.0


@jit_inline
def sample_light(s, u0, u1, u2):
    """Pick an emissive triangle (by power) and a point on it (by area).

    Returns ``(k, mat, q_o, q_err, n_o, q_w, n_w)``: the instance and material, the point in
    object space with its error bound and the unit object normal (for spawning the shadow ray's
    end), and the world point and unit world normal.
    """
    e = np.searchsorted(s.light_cdf, u0, side="right")
    if e >= s.light_cdf.shape[0]:
        e = s.light_cdf.shape[0] - 1
    k = s.light_inst[e]
    j = s.light_tri[e]
    tv = pick(s.tri_verts, s.inst_pool[k])
    b0, b1, b2 = square_to_uniform_triangle(u1, u2)
    q_o, q_err = hit_point(tv, j, b0, b1, b2)
    n_o, _ = geometric_normal(tv, j)
    if s.inst_identity[k]:
        return k, material_of(s, k, j), q_o, q_err, n_o, q_o, n_o
    n = apply_normal(s.inst_inv, k, n_o)
    inv_len = 1.0 / np.sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2])
    n_w = (n[0] * inv_len, n[1] * inv_len, n[2] * inv_len)
    return k, material_of(s, k, j), q_o, q_err, n_o, apply_point(s.inst_xform, k, q_o), n_w

"""Tangent-space normal maps: the tangent frame of a hit and the normal a map gives it.

The frame is the triangle's own: tangent ``dp/du`` and bitangent ``dp/dv`` from its corners'
positions and UVs (pbrt-v4's ``Triangle::InteractionFromIntersection``), carried to the world
by the instance's transform, the tangent made orthogonal to the shading normal (Gram-Schmidt)
and the bitangent their cross product, signed like ``dp/dv``. A texel ``c`` (read linearly) is
the vector ``(2 c - 1)`` in that frame, its tangential part scaled by the map's strength, as
glTF's ``normalTexture`` defines it. Per-triangle frames are not MikkTSpace: where a mesh's UV
layout shears across triangles, a map baked against MikkTSpace tangents tilts slightly
differently (docs/materials.md).
"""

import math

import numpy as np

from tracer.compiled.arrays import pick
from tracer.geometry.transforms import apply_vector
from tracer.kernel.jit import jit_inline
from tracer.shading.textures import bilinear, hit_uv

MIN_LIFT = 1e-3
"""A mapped normal must keep at least this cosine with the geometric normal, else the shading
normal stays as it was (a map cannot turn a surface inside out)."""


@jit_inline
def _unit(v):
    length2 = v[0] * v[0] + v[1] * v[1] + v[2] * v[2]
    if not length2 > 1e-30:
        return False, v
    inv = 1.0 / math.sqrt(length2)
    return True, (v[0] * inv, v[1] * inv, v[2] * inv)


@jit_inline
def mapped_normal(s, mat, k, j, b0, b1, b2, ns, ng):
    """Material ``mat``'s normal map applied at the hit to ``ns`` (the world shading normal on
    the side of the geometric ``ng``): ``(True, n)``, or ``(False, ns)`` where the material has
    no map or the triangle no usable UV frame."""
    t = s.mat_normal_map[mat]
    if t < 0:
        return False, ns
    pool = s.inst_pool[k]
    uv = pick(s.tri_uv, pool)
    if uv.shape[0] == 0:
        return False, ns
    tv = pick(s.tri_verts, pool)
    e1 = (np.float64(tv[j, 3] - tv[j, 0]), np.float64(tv[j, 4] - tv[j, 1]),
          np.float64(tv[j, 5] - tv[j, 2]))  # fmt: skip
    e2 = (np.float64(tv[j, 6] - tv[j, 0]), np.float64(tv[j, 7] - tv[j, 1]),
          np.float64(tv[j, 8] - tv[j, 2]))  # fmt: skip
    du1 = np.float64(uv[j, 2] - uv[j, 0])
    dv1 = np.float64(uv[j, 3] - uv[j, 1])
    du2 = np.float64(uv[j, 4] - uv[j, 0])
    dv2 = np.float64(uv[j, 5] - uv[j, 1])
    det = du1 * dv2 - du2 * dv1
    if det == 0.0:
        return False, ns
    r = 1.0 / det
    dpdu = ((dv2 * e1[0] - dv1 * e2[0]) * r, (dv2 * e1[1] - dv1 * e2[1]) * r,
            (dv2 * e1[2] - dv1 * e2[2]) * r)  # fmt: skip
    dpdv = ((du1 * e2[0] - du2 * e1[0]) * r, (du1 * e2[1] - du2 * e1[1]) * r,
            (du1 * e2[2] - du2 * e1[2]) * r)  # fmt: skip
    if not s.inst_identity[k]:
        dpdu = apply_vector(s.inst_xform, k, dpdu)
        dpdv = apply_vector(s.inst_xform, k, dpdv)
    c = dpdu[0] * ns[0] + dpdu[1] * ns[1] + dpdu[2] * ns[2]
    ok, tangent = _unit((dpdu[0] - c * ns[0], dpdu[1] - c * ns[1], dpdu[2] - c * ns[2]))
    if not ok:
        return False, ns
    bitangent = (ns[1] * tangent[2] - ns[2] * tangent[1], ns[2] * tangent[0] - ns[0] * tangent[2],
                 ns[0] * tangent[1] - ns[1] * tangent[0])  # fmt: skip
    if bitangent[0] * dpdv[0] + bitangent[1] * dpdv[1] + bitangent[2] * dpdv[2] < 0.0:
        bitangent = (-bitangent[0], -bitangent[1], -bitangent[2])
    u, v = hit_uv(s, k, j, b0, b1, b2)
    texel = bilinear(s.tex_pixels, s.tex_info, s.tex_scale, t, u, v)
    strength = s.mat_normal_strength[mat]
    x = (2.0 * texel[0] - 1.0) * strength
    y = (2.0 * texel[1] - 1.0) * strength
    z = 2.0 * texel[2] - 1.0
    ok, n = _unit((x * tangent[0] + y * bitangent[0] + z * ns[0],
                   x * tangent[1] + y * bitangent[1] + z * ns[1],
                   x * tangent[2] + y * bitangent[2] + z * ns[2]))  # fmt: skip
    if not ok or n[0] * ng[0] + n[1] * ng[1] + n[2] * ng[2] < MIN_LIFT:
        return False, ns
    return True, n

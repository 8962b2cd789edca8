"""The alpha test at a candidate hit: whether a triangle of a material with ``alpha`` is there.

Traversals built with it (``tracer.geometry.scene_intersect``: the kernels' material builds)
call :func:`hidden` for every triangle hit that would be their best so far, as pbrt-v4's
``GeometricPrimitive::Intersect`` tests alpha inside the intersection: a hidden hit is skipped
and the traversal goes on, so closest hits and shadow rays see through it alike.

A ``mask`` triangle is hidden where its alpha (value times the alpha texture's bilinear lookup)
is below the cutoff. A ``blend`` triangle is hidden with probability ``1 - alpha``, decided by a
hash of the ray (object-space origin and direction bits) and the triangle (pbrt-v4 hashes the
ray alone; the triangle keeps two surfaces on one ray independent): a pure function of the ray
and the hit, so any split of a frame, any thread count and any traversal order decide the same.
"""

import numpy as np
from llvmlite import ir
from numba import types
from numba.extending import intrinsic

from tracer.compiled.arrays import pick
from tracer.kernel.jit import jit, jit_inline
from tracer.maths.rng import mix64
from tracer.shading.textures import CUTOFF, ENTRY, MASK, MODE, OPAQUE, VALUE, bilinear

_INV_2_53 = 1.0 / 9007199254740992.0
_S11 = np.uint64(11)


@intrinsic
def _bits(typingctx, x):
    """The IEEE bits of a float64 as a uint64."""
    if x != types.float64:
        return None

    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], ir.IntType(64))

    return types.uint64(types.float64), codegen


@jit
def ray_uniform(o, d, k, j):
    """A uniform in [0, 1) from the ray ``(o, d)`` and the triangle (instance ``k``, row ``j``)."""
    h = mix64(np.uint64(k) << np.uint64(32) | np.uint64(j))
    for x in (o[0], o[1], o[2], d[0], d[1], d[2]):
        h = mix64(h ^ _bits(np.float64(x)))
    return np.float64(h >> _S11) * _INV_2_53


@jit
def hidden_at(mat_alpha, inst_material, tri_material, uv, pixels, info, scale, k, j, b0, b1, b2,
              o, d):  # fmt: skip
    """Whether instance ``k``'s triangle row ``j`` (its pool's ``tri_material`` and ``uv``
    rows), hit at barycentrics (b0, b1, b2) by the object-space ray ``(o, d)``, is not there:
    its material's alpha (its value times its alpha image's bilinear lookup) is below the
    cutoff (mask) or, with probability ``1 - alpha``, the hash of ray and triangle (blend).
    Not inlined: the traversals keep one call, and its code compiles once."""
    m = inst_material[k]
    if m < 0:
        m = tri_material[j]
    mode = mat_alpha[m, MODE]
    if mode == OPAQUE:
        return False
    a = mat_alpha[m, VALUE]
    entry = np.int64(mat_alpha[m, ENTRY])
    if entry >= 0 and uv.shape[0] > 0:
        u = b0 * uv[j, 0] + b1 * uv[j, 2] + b2 * uv[j, 4]
        v = b0 * uv[j, 1] + b1 * uv[j, 3] + b2 * uv[j, 5]
        a *= bilinear(pixels, info, scale, entry, u, v)[0]
    if mode == MASK:
        return not a >= mat_alpha[m, CUTOFF]
    return not ray_uniform(o, d, k, j) < a


@jit_inline
def hidden(s, k, j, b0, b1, b2, o, d):
    """:func:`hidden_at` for instance ``k``'s row ``j`` of the scene ``s``; False at once
    without the plan's alpha table."""
    if s.mat_alpha.shape[0] == 0:
        return False
    pool = s.inst_pool[k]
    return hidden_at(s.mat_alpha, s.inst_material, pick(s.tri_material, pool),
                     pick(s.tri_uv, pool), s.tex_pixels, s.tex_info, s.tex_scale, k, j, b0, b1,
                     b2, o, d)  # fmt: skip

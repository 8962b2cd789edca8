"""The light tree: choosing one emissive triangle by its importance as seen from a point.

A 4-wide BVH over the emissive triangles (built by ``tracer.compiled.light_tree``), each child
slot of a node bounding its triangles' positions, the cone of their normals and their summed
power. From a shading point ``p`` with normal ``n`` a walk from the root picks a slot by the
four slots' importance (pbrt-v4's ``LightBounds::Importance``: power over squared distance,
times the best cosines the bounds allow at the emitters and at ``p``) until it reaches a
triangle; the triangle's probability is the product of the choices. The four importances of a
node are one LLVM vector computation (``_importance4``). ``tree_pmf`` recomputes the product
for a given triangle from its trail (two bits per level: the slot), with the same expressions,
so sampling and MIS see the same bits. ``docs/effects.md`` ("Many lights").

Emitters are area lights: they emit over the hemisphere of their normal (two-sided ones over
both), so a slot's emission cone is its normal cone widened by 90 degrees. The importance at
``p`` counts only light arriving above ``n``: the BSDFs that sample lights reflect only.
"""

import numpy as np
from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

from tracer.kernel import vector_ir
from tracer.kernel.jit import jit, jit_inline
from tracer.kernel.vector_ir import is_c_matrix, row_address

WIDTH = 4
"""Child slots per node."""
NODE = 11
"""Fields of a slot. A node's row of ``light_tree_nodes`` holds each field for its four slots
side by side (column ``field * WIDTH + slot``): ``CENTRE`` (3) and ``RADIUS2`` the sphere around
the box of the slot's triangles (its centre and squared radius), ``AXIS`` (3) the unit axis of
their normals' cone, ``COS_O`` and ``SIN_O`` its half-angle, ``PHI`` their summed selection
weight (0: an empty slot), ``TWO_SIDED`` 1 if any of them emits on both sides."""
CENTRE = 0
RADIUS2 = 3
AXIS = 4
COS_O = 7
SIN_O = 8
PHI = 9
TWO_SIDED = 10

ONE_MINUS_EPSILON = 0.99999999999999989
"""The largest float64 below 1: a rescaled random number stays in [0, 1)."""
NOT_TREE = -2
"""``tree_pick``'s entry when the random number falls on the lights beside the tree."""
TINY = 1e-300
"""Stands in for a zero radius where a point lies inside a slot's sphere."""


@intrinsic
def _importance4(typingctx, nodes, i, px, py, pz, nx, ny, nz):
    """How much each slot of node ``i`` may light the point ``p`` with normal ``n``: a bound
    on power / distance^2 times the emitter and receiver cosines (0 only where none can), for
    the four slots at once as LLVM vector code. Inside a slot's sphere every direction and
    cosine is possible: power / radius^2. Outside, the emitter side takes the angle from the
    cone to ``p`` less the cone's and the sphere's half-angles, the receiver side the angle
    from ``n`` to the sphere less its half-angle. IEEE operations only, in a fixed order, so
    every CPU gets the same bits (``tests/tracer/test_light_tree.py`` checks them against a
    numpy transcription). Needs a C-contiguous float64 ``nodes``."""
    if not is_c_matrix(nodes, types.float64):
        return None
    f64 = types.float64
    sig = types.UniTuple(f64, WIDTH)(nodes, i, f64, f64, f64, f64, f64, f64)

    def codegen(context, builder, signature, args):
        nodes_, i_, px_, py_, pz_, nx_, ny_, nz_ = args
        i64 = ir.IntType(64)
        vd = ir.VectorType(ir.DoubleType(), WIDTH)
        base = row_address(context, builder, signature.args[0], nodes_, i_, signature.args[1])
        unary = ir.FunctionType(vd, [vd])
        sqrt = cgutils.get_or_insert_function(builder.module, unary, f"llvm.sqrt.v{WIDTH}f64")
        fabs = cgutils.get_or_insert_function(builder.module, unary, f"llvm.fabs.v{WIDTH}f64")

        def field(f):
            offset = ir.Constant(i64, f * WIDTH * 8)
            return builder.load(
                builder.bitcast(builder.gep(base, [offset]), vd.as_pointer()), align=8
            )

        def splat(x):
            return vector_ir.splat(builder, vd, x)

        def const(x):
            return splat(ir.Constant(ir.DoubleType(), x))

        add, sub, mul, div = builder.fadd, builder.fsub, builder.fmul, builder.fdiv

        def above(a, b):  # a > b, and never for a NaN
            return builder.fcmp_ordered(">", a, b)

        def positive_part(x):
            return builder.select(above(x, const(0.0)), x, const(0.0))

        dx = sub(splat(px_), field(CENTRE))
        dy = sub(splat(py_), field(CENTRE + 1))
        dz = sub(splat(pz_), field(CENTRE + 2))
        d2 = add(add(mul(dx, dx), mul(dy, dy)), mul(dz, dz))
        r2 = field(RADIUS2)
        phi = field(PHI)
        inv = div(const(1.0), builder.call(sqrt, [d2]))
        wx, wy, wz = mul(dx, inv), mul(dy, inv), mul(dz, inv)
        sin2_b = div(r2, d2)
        cos_b = builder.call(sqrt, [sub(const(1.0), sin2_b)])
        sin_b = builder.call(sqrt, [sin2_b])
        # Emitter side: the angle from the cone's axis to p, less the cone's half-angle.
        cos_w = add(add(mul(field(AXIS), wx), mul(field(AXIS + 1), wy)), mul(field(AXIS + 2), wz))
        two_sided = builder.fcmp_ordered("!=", field(TWO_SIDED), const(0.0))
        cos_w = builder.select(two_sided, builder.call(fabs, [cos_w]), cos_w)
        cos_o, sin_o = field(COS_O), field(SIN_O)
        sin_w = builder.call(sqrt, [positive_part(sub(const(1.0), mul(cos_w, cos_w)))])
        cos_x = add(mul(cos_w, cos_o), mul(sin_w, sin_o))
        sin_x = sub(mul(sin_w, cos_o), mul(cos_w, sin_o))
        cos_xb = add(mul(cos_x, cos_b), mul(sin_x, sin_b))
        in_cone = builder.or_(above(cos_w, cos_o), above(cos_x, cos_b))
        cos_e = builder.select(in_cone, const(1.0), cos_xb)
        # Receiver side: the angle from n to the sphere, less the sphere's half-angle.
        cos_a = builder.fneg(
            add(add(mul(splat(nx_), wx), mul(splat(ny_), wy)), mul(splat(nz_), wz))
        )
        sin_a = builder.call(sqrt, [positive_part(sub(const(1.0), mul(cos_a, cos_a)))])
        cos_r = builder.select(
            above(cos_a, cos_b), const(1.0), add(mul(cos_a, cos_b), mul(sin_a, sin_b))
        )
        lit = builder.and_(above(cos_e, const(0.0)), above(cos_r, const(0.0)))
        outside = builder.select(lit, div(mul(mul(phi, cos_e), cos_r), d2), const(0.0))
        inside = div(phi, builder.select(above(r2, const(TINY)), r2, const(TINY)))
        result = builder.select(builder.fcmp_ordered("<=", d2, r2), inside, outside)
        lanes = [builder.extract_element(result, ir.Constant(i64, k)) for k in range(WIDTH)]
        return context.make_tuple(builder, signature.return_type, lanes)

    return sig, codegen


@jit_inline
def importances(nodes, i, p, n):
    """The importance of each of node ``i``'s four slots for the point ``p`` with normal
    ``n`` (``_importance4``)."""
    return _importance4(nodes, i, p[0], p[1], p[2], n[0], n[1], n[2])


@jit
def tree_sample(nodes, child, p, n, u):
    """A triangle for the point ``p`` with normal ``n``, chosen by ``u`` in [0, 1):
    ``(light, pmf)``, its index among the emissive triangles (the first entries of the light
    table) and probability; ``(-1, 0.0)`` when no triangle can light ``p``. Each level maps
    ``u`` onto the slots' importances laid end to end in slot order, and rescales it."""
    i = 0
    pmf = 1.0
    while True:
        c = importances(nodes, i, p, n)
        total = ((c[0] + c[1]) + c[2]) + c[3]
        if not total > 0.0:
            return -1, 0.0
        target = u * total
        start = 0.0
        chosen = -1
        chosen_start = 0.0
        for k in range(WIDTH):
            if c[k] > 0.0:
                chosen = k  # the last slot with importance takes what rounding leaves
                chosen_start = start
                if target < start + c[k]:
                    break
            start += c[k]
        u = min((target - chosen_start) / c[chosen], ONE_MINUS_EPSILON)
        pmf *= c[chosen] / total
        nxt = child[i, chosen]
        if nxt < 0:
            return -1 - nxt, pmf
        i = nxt


@jit
def tree_pmf(nodes, child, bits, light, p, n):
    """The probability with which ``tree_sample`` picks triangle ``light`` for ``p`` and
    ``n`` (the same products in the same order)."""
    trail = bits[light]
    i = 0
    pmf = 1.0
    while True:
        c = importances(nodes, i, p, n)
        total = ((c[0] + c[1]) + c[2]) + c[3]
        if not total > 0.0:
            return 0.0
        k = np.int64(trail & np.uint64(WIDTH - 1))
        pmf *= c[k] / total
        nxt = child[i, k]
        if nxt < 0:
            return pmf
        i = nxt
        trail = trail >> np.uint64(2)


@jit
def tree_light_of(keys, key_light, k, j):
    """The index among the emissive triangles of row ``j`` of instance ``k``'s pool, or -1."""
    key = (np.int64(k) << np.int64(32)) | np.int64(j)
    at = np.searchsorted(keys, key)
    if at < keys.shape[0] and keys[at] == key:
        return key_light[at]
    return -1


@jit_inline
def _share(cdf, area):
    """The probability that light selection picks the tree (its emissive triangles are the
    first entries of the power CDF): their share of the power."""
    return cdf[area.shape[0] - 1]


@jit
def tree_pick(cdf, nodes, child, area, u0, p, n):
    """Light selection by ``u0`` with the tree: ``(entry, density)``, a triangle picked by the
    tree from its share of ``u0`` (rescaled) and its area density (share times PMF over area),
    or ``(NOT_TREE, -1.0)`` when ``u0`` falls on the other lights (pick them by power), or
    ``(-1, 0.0)`` when the tree has no triangle for ``p``."""
    share = _share(cdf, area)
    if not u0 < share:
        return NOT_TREE, -1.0
    e, pmf = tree_sample(nodes, child, p, n, min(u0 / share, ONE_MINUS_EPSILON))
    if e < 0:
        return -1, 0.0
    return e, share * pmf / area[e]


@jit
def tree_hit_density(cdf, nodes, child, bits, area, keys, key_light, k, j, p, n):
    """The area density with which ``tree_pick`` at ``p`` (normal ``n``) picks the point of
    row ``j`` of instance ``k``'s pool that a ray hit (0 if it is not an emissive triangle)."""
    e = tree_light_of(keys, key_light, k, j)
    if e < 0:
        return 0.0
    return _share(cdf, area) * tree_pmf(nodes, child, bits, e, p, n) / area[e]

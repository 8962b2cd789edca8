"""Ray queries against a :class:`tracer.geometry.bvh.TraversalBVH`: closest hit and any hit.

Robustness without epsilons (docs/robustness.md):

* Triangles: the watertight test of Woop, Benthin and Wald (JCGT 2013), evaluated in float64 on
  float32 vertices. A ray through a shared edge or vertex hits at least one of the triangles,
  because both evaluate the shared edge function from the same operands.
* Hits closer than the conservative error bound of their own ``t`` are rejected (pbrt-v4's
  ``deltaT``), so a ray can never report its own origin surface at t ~ 0.
* Boxes (four per node, ``tracer.geometry.bvh``): the slab test ignores the NaN that
  ``0 * inf`` makes when a ray with a zero direction component starts exactly on a slab plane
  (a NaN comparison is false, so it never tightens the interval), and widens ``t_far`` by
  ``1 + 2 gamma(3)``.
* Hit points carry a conservative error bound; :func:`offset_ray_origin` moves a spawned ray's
  origin just past it, along the geometric normal, with a margin for its own rounding.

All functions are ``inline='always'``: they take arrays, and a non-inlined call would cost
reference-count traffic on every ray.
"""

import math
from collections.abc import Callable

import numpy as np
from llvmlite import ir
from numba import types
from numba.extending import intrinsic

from tracer.kernel import vector_ir
from tracer.kernel.jit import jit, jit_inline
from tracer.kernel.vector_ir import is_c_matrix, row_address

MACHINE_EPSILON = np.finfo(np.float64).eps * 0.5


def gamma(n):
    """Bound on the relative error of n float64 operations (pbrt's gamma)."""
    return (n * MACHINE_EPSILON) / (1.0 - n * MACHINE_EPSILON)


GAMMA2 = gamma(2)
GAMMA3 = gamma(3)
GAMMA5 = gamma(5)
GAMMA7 = gamma(7)
SLAB_WIDEN = 1.0 + 2.0 * GAMMA3
RANGE_WIDEN = 1.0 + 4.0 * MACHINE_EPSILON
"""Covers the roundings of ``t_max * det`` and of ``t_scaled / det`` in the triangle test's
early out, so that it rejects only triangles whose computed ``t`` exceeds ``t_max``."""
NO_INSTANCE = np.iinfo(np.int32).max
"""Key of "no hit yet" in the closest-hit tie-break: above every real instance or triangle."""
NO_ENTRY = np.iinfo(np.int32).min
"""No node or leaf to enter next (child references are never this low)."""
OFFSET_ROUNDING_MARGIN = 8.0 * MACHINE_EPSILON
"""Covers sum_i |n_i| * ulp(o_i) <= sqrt(3) * 2 eps * max|o_i| for the rounded origin o."""


@jit
def slab_setup(d):
    """The box test's per-ray constants: ``(ix, iy, iz, nx, ny, nz)`` of :func:`ray_setup`."""
    ix = 1.0 / d[0]
    iy = 1.0 / d[1]
    iz = 1.0 / d[2]
    nx = 3 if ix < 0.0 else 0
    ny = 3 if iy < 0.0 else 0
    nz = 3 if iz < 0.0 else 0
    return ix, iy, iz, nx, ny, nz


@jit
def ray_setup(o, d):
    """Per-ray constants: reciprocal direction and the watertight test's axis permutation and shear.

    Returns ``(ix, iy, iz, nx, ny, nz, kx, ky, kz, sx, sy, sz, okx, oky, okz)``. ``n*`` is the
    offset of each axis's near box plane (0 for min, 3 for max; -0.0 counts as negative). ``kz``
    is the dominant axis of the direction; kx, ky follow it cyclically and are swapped when
    ``d[kz] < 0`` to keep the winding; ``ok*`` are the origin's coordinates in that order.
    """
    dx, dy, dz = d
    ix, iy, iz, nx, ny, nz = slab_setup(d)
    ax = abs(dx)
    ay = abs(dy)
    az = abs(dz)
    if ax > ay and ax > az:
        kz = 0
    elif ay > az:
        kz = 1
    else:
        kz = 2
    kx = kz + 1 if kz < 2 else 0
    ky = kx + 1 if kx < 2 else 0
    dkz = d[kz]
    if dkz < 0.0:
        kx, ky = ky, kx
    sz = 1.0 / dkz
    sx = d[kx] * sz
    sy = d[ky] * sz
    return ix, iy, iz, nx, ny, nz, kx, ky, kz, sx, sy, sz, o[kx], o[ky], o[kz]


@jit_inline
def slab(bounds, node, s, ox, oy, oz, ix, iy, iz, nx, ny, nz, t_max):
    """Entry distance of the ray into the box of child slot ``s`` of wide node ``node``
    (``tracer.geometry.bvh`` layout) within [0, t_max], or inf.

    ``nx, ny, nz`` select each axis's near plane (0: min, 3: max) from the direction's sign, so
    no per-box swaps are needed. Comparisons are written so that a NaN slab distance (0 * inf)
    constrains nothing.
    """
    near = 0.0
    far = t_max
    t = (bounds[node, 4 * nx + s] - ox) * ix
    if t > near:
        near = t
    t = (bounds[node, 12 - 4 * nx + s] - ox) * ix
    if t < far:
        far = t
    t = (bounds[node, 4 + 4 * ny + s] - oy) * iy
    if t > near:
        near = t
    t = (bounds[node, 16 - 4 * ny + s] - oy) * iy
    if t < far:
        far = t
    t = (bounds[node, 8 + 4 * nz + s] - oz) * iz
    if t > near:
        near = t
    t = (bounds[node, 20 - 4 * nz + s] - oz) * iz
    if t < far:
        far = t
    return near if near <= far * SLAB_WIDEN else np.inf


@jit_inline
def nearer_first(ta, ca, tb, cb):
    """The pair (t, child) with the smaller t first."""
    if tb < ta:
        return tb, cb, ta, ca
    return ta, ca, tb, cb


@intrinsic
def _slab4(typingctx, bounds, node, nx, ny, nz, ox, oy, oz, ix, iy, iz, t_max):
    """:func:`slab` for all four slots of a node at once, as LLVM vector code (numba does not
    vectorise the four scalar tests itself): each bound row is one <4 x float> load, widened
    to double; the same IEEE operations as :func:`slab` in the same order, so the same results.
    Also maps an entry past ``t_max`` to inf. Needs a C-contiguous float32 ``bounds``."""
    if not is_c_matrix(bounds, types.float32):
        return None
    f64 = types.float64
    sig = types.UniTuple(f64, 4)(bounds, node, nx, ny, nz, f64, f64, f64, f64, f64, f64, f64)

    def codegen(context, builder, signature, args):
        b, node_, nx_, ny_, nz_, ox_, oy_, oz_, ix_, iy_, iz_, t_max_ = args
        i64 = ir.IntType(64)
        vf = ir.VectorType(ir.FloatType(), 4)
        vd = ir.VectorType(ir.DoubleType(), 4)
        base = row_address(context, builder, signature.args[0], b, node_, signature.args[1])

        def splat(x):
            return vector_ir.splat(builder, vd, x)

        def load_row(offset_bytes):
            ptr = builder.bitcast(builder.gep(base, [offset_bytes]), vf.as_pointer())
            return builder.fpext(builder.load(ptr, align=4), vd)

        def row_offset(start, scale, n, n_type):
            # start + scale * n bytes: n (0 or 3) moves between the min and the max rows.
            n64 = context.cast(builder, n, n_type, types.int64)
            return builder.add(ir.Constant(i64, start), builder.mul(n64, ir.Constant(i64, scale)))

        near = splat(ir.Constant(ir.DoubleType(), 0.0))
        far = splat(t_max_)
        axes = (
            (nx_, signature.args[2], ox_, ix_, 0),
            (ny_, signature.args[3], oy_, iy_, 16),
            (nz_, signature.args[4], oz_, iz_, 32),
        )
        for n, n_type, o, inv, start in axes:
            o_v = splat(o)
            inv_v = splat(inv)
            # near plane: row (axis + n), far plane: row (axis + 3 - n); rows are 16 bytes.
            t = builder.fmul(builder.fsub(load_row(row_offset(start, 16, n, n_type)), o_v), inv_v)
            near = builder.select(builder.fcmp_ordered(">", t, near), t, near)
            t = builder.fmul(
                builder.fsub(load_row(row_offset(start + 48, -16, n, n_type)), o_v), inv_v
            )
            far = builder.select(builder.fcmp_ordered("<", t, far), t, far)
        widened = builder.fmul(far, splat(ir.Constant(ir.DoubleType(), SLAB_WIDEN)))
        hit = builder.and_(
            builder.fcmp_ordered("<=", near, widened),
            builder.fcmp_ordered("<=", near, splat(t_max_)),
        )
        result = builder.select(hit, near, splat(ir.Constant(ir.DoubleType(), np.inf)))
        lanes = [builder.extract_element(result, ir.Constant(i64, k)) for k in range(4)]
        return context.make_tuple(builder, signature.return_type, lanes)

    return sig, codegen


@jit_inline
def visit(bounds, child, node, ox, oy, oz, ix, iy, iz, nx, ny, nz, floor, t_max):
    """Keys of the four child boxes of wide node ``node``: the entry distance, raised to at
    least ``floor`` (the key of ``node`` itself), or inf for a miss or an entry past ``t_max``;
    sorted nearest first with the child references: ``(t0, c0, ..., t3, c3)``. A box entered
    exactly at ``t_max`` counts: it may still hold a tie with a lower key."""
    t0, t1, t2, t3 = _slab4(bounds, node, nx, ny, nz, ox, oy, oz, ix, iy, iz, t_max)
    t0 = max(t0, floor)
    t1 = max(t1, floor)
    t2 = max(t2, floor)
    t3 = max(t3, floor)
    return nearest_first4(
        t0, child[node, 0], t1, child[node, 1], t2, child[node, 2], t3, child[node, 3]
    )


@jit_inline
def nearest_first4(t0, c0, t1, c1, t2, c2, t3, c3):
    """Four (t, item) pairs sorted by t, nearest first: a network of five compare-exchanges."""
    t0, c0, t1, c1 = nearer_first(t0, c0, t1, c1)
    t2, c2, t3, c3 = nearer_first(t2, c2, t3, c3)
    t0, c0, t2, c2 = nearer_first(t0, c0, t2, c2)
    t1, c1, t3, c3 = nearer_first(t1, c1, t3, c3)
    t1, c1, t2, c2 = nearer_first(t1, c1, t2, c2)
    return t0, c0, t1, c1, t2, c2, t3, c3


@jit_inline
def push_far(stack_node, stack_t, sp, t1, c1, t2, c2, t3, c3):
    """Push the entered boxes other than the nearest, farthest first (so nearer ones pop
    first); returns the new stack pointer. Writes one entry past the last push at most."""
    stack_node[sp] = c3
    stack_t[sp] = t3
    sp += 1 if t3 < np.inf else 0
    stack_node[sp] = c2
    stack_t[sp] = t2
    sp += 1 if t2 < np.inf else 0
    stack_node[sp] = c1
    stack_t[sp] = t1
    sp += 1 if t1 < np.inf else 0
    return sp


@jit_inline
def intersect_triangle(tri_verts, j, okx, oky, okz, kx, ky, kz, sx, sy, sz, t_max):
    """Watertight ray-triangle test for triangle ``j``, with the constants of :func:`ray_setup`.

    Returns ``(t, b0, b1, b2)`` with ``t`` in (0, t_max), or ``t = inf`` for a miss.
    """
    # Translate to the ray origin, permute so the dominant axis is z, shear to align the ray with z.
    az_ = tri_verts[j, kz] - okz
    bz_ = tri_verts[j, 3 + kz] - okz
    cz_ = tri_verts[j, 6 + kz] - okz
    ax = tri_verts[j, kx] - okx - sx * az_
    ay = tri_verts[j, ky] - oky - sy * az_
    bx = tri_verts[j, 3 + kx] - okx - sx * bz_
    by = tri_verts[j, 3 + ky] - oky - sy * bz_
    cx = tri_verts[j, 6 + kx] - okx - sx * cz_
    cy = tri_verts[j, 6 + ky] - oky - sy * cz_
    # Edge functions.
    u = cx * by - cy * bx
    v = ax * cy - ay * cx
    w = bx * ay - by * ax
    if (u < 0.0 or v < 0.0 or w < 0.0) and (u > 0.0 or v > 0.0 or w > 0.0):
        return np.inf, 0.0, 0.0, 0.0
    det = u + v + w
    if det == 0.0:
        return np.inf, 0.0, 0.0, 0.0
    az = sz * az_
    bz = sz * bz_
    cz = sz * cz_
    t_scaled = u * az + v * bz + w * cz
    # An early out before the division where t is surely past t_max; the range test proper is
    # on t itself, so that accepting a triangle never depends on how t_max * det rounds.
    far = t_max * det * RANGE_WIDEN
    if det < 0.0 and (t_scaled >= 0.0 or t_scaled < far):
        return np.inf, 0.0, 0.0, 0.0
    if det > 0.0 and (t_scaled <= 0.0 or t_scaled > far):
        return np.inf, 0.0, 0.0, 0.0
    inv_det = 1.0 / det
    t = t_scaled * inv_det
    if t > t_max:
        return np.inf, 0.0, 0.0, 0.0
    # Reject hits within the error bound of t = 0 (pbrt-v4, Triangle::Intersect).
    # x and y were sheared with the unscaled z (|sx|, |sy| <= 1), so their error bounds use it;
    # the scaled z (in units of t) enters only through delta_z.
    max_zt = max(abs(az), max(abs(bz), abs(cz)))
    max_z = max(abs(az_), max(abs(bz_), abs(cz_)))
    max_xt = max(abs(ax), max(abs(bx), abs(cx)))
    max_yt = max(abs(ay), max(abs(by), abs(cy)))
    delta_z = GAMMA3 * max_zt
    delta_x = GAMMA5 * (max_xt + max_z)
    delta_y = GAMMA5 * (max_yt + max_z)
    delta_e = 2.0 * (GAMMA2 * max_xt * max_yt + delta_y * max_xt + delta_x * max_yt)
    max_e = max(abs(u), max(abs(v), abs(w)))
    delta_t = 3.0 * (GAMMA3 * max_e * max_zt + delta_e * max_zt + delta_z * max_e) * abs(inv_det)
    if t <= delta_t:
        return np.inf, 0.0, 0.0, 0.0
    return t, u * inv_det, v * inv_det, w * inv_det


@jit_inline
def closer(t, inst, prim, t_best, inst_best, prim_best):
    """Whether a hit (t, inst, prim) beats the best so far: nearer, or as near and of a lower
    (instance, triangle) key. With the hit keys of :func:`blas_closest` (``t`` is a key there),
    this makes the closest hit independent of the order in which the BVH visits triangles, and
    of the tree's shape except at ulp-level near-ties (see there)."""
    if t < t_best:
        return True
    if t > t_best:
        return False
    return inst < inst_best or (inst == inst_best and prim < prim_best)


@jit_inline
def enter_any(bounds, child, node, ox, oy, oz, ix, iy, iz, nx, ny, nz, t_max, stack_node, sp):
    """For an any-hit traversal: the children of wide node ``node`` whose boxes the ray enters
    before ``t_max``, in slot order; returns the first (``NO_ENTRY`` if none) and the stack
    pointer after pushing the others."""
    t0, t1, t2, t3 = _slab4(bounds, node, nx, ny, nz, ox, oy, oz, ix, iy, iz, t_max)
    entry = NO_ENTRY
    for t, s in ((t0, 0), (t1, 1), (t2, 2), (t3, 3)):
        if t < t_max:
            if entry == NO_ENTRY:
                entry = child[node, s]
            else:
                stack_node[sp] = child[node, s]
                sp += 1
    return entry, sp


def closest_traversal(alpha: bool) -> Callable[..., tuple]:
    """:func:`blas_closest`; with ``alpha`` its twin that skips a candidate hit the global
    ``hidden`` rejects (``tracer.shading.alpha``, bound by ``tracer.kernel.jit.with_globals``).
    ``alpha`` is a closure constant: without it the test is removed before type inference."""

    def blas_closest(
        node_bounds,
        node_child,
        tri_verts,
        tri_prim,
        root,
        inst,
        floor,
        o,
        d,
        t_key,
        t_hit,
        h_inst,
        h_j,
        h_prim,
        hb0,
        hb1,
        hb2,
        stack_node,
        stack_t,
        sp0,
        s,
    ):
        """Closest-hit traversal of one BVH from node ``root`` (entered with key ``floor``)
        for the ray ``o + t d``.

        Continues a search whose best hit so far is ``(t_key, t_hit, h_inst, h_j, h_prim, hb0,
        hb1, hb2)``: its key, its distance, its triangle's row ``h_j`` and original index
        ``h_prim``, and barycentrics; triangles here belong to instance ``inst`` of the scene
        ``s`` (read by the alpha test only). Uses the stacks above ``sp0``. Returns the updated
        best hit and the work done: ``(t_key, t_hit, h_inst, h_j, h_prim, hb0, hb1, hb2,
        cost)``.

        A hit's key is its ``t`` raised to the keys of the boxes the traversal entered to reach
        it (each box's key is its entry distance, raised to its parent's key). The best hit is
        the least by (key, instance, triangle): a box is dropped only when its key exceeds the
        best key, and every hit inside it has a key at least the box's, so what is dropped can
        never win and the result does not depend on the order of the visits in this tree (nor
        on a packet's). The key equals ``t`` except where a hit's computed ``t`` rounds below a
        box's computed entry; only there can another tree over the same triangles (refitted,
        rebuilt) pick another hit.
        """
        ox, oy, oz = o
        ix, iy, iz, nx, ny, nz, kx, ky, kz, sx, sy, sz, okx, oky, okz = ray_setup(o, d)
        cost = 0
        sp = sp0
        entry = root
        entry_key = floor
        while True:
            if entry >= 0:
                # An interior node: go on into the nearest box entered, keep the others.
                cost += 1
                t0, c0, t1, c1, t2, c2, t3, c3 = visit(
                    node_bounds, node_child, entry, ox, oy, oz, ix, iy, iz, nx, ny, nz, entry_key,
                    t_key,
                )  # fmt: skip
                sp = push_far(stack_node, stack_t, sp, t1, c1, t2, c2, t3, c3)
                if t0 < np.inf:
                    entry = c0
                    entry_key = t0
                    continue
            else:
                v = -1 - entry
                for j in range(v >> 3, (v >> 3) + (v & 7)):
                    cost += 1
                    t, b0, b1, b2 = intersect_triangle(
                        tri_verts, j, okx, oky, okz, kx, ky, kz, sx, sy, sz, t_key
                    )
                    key = max(t, entry_key)
                    if t < np.inf and closer(key, inst, tri_prim[j], t_key, h_inst, h_prim):
                        if alpha and hidden(s, inst, j, b0, b1, b2, o, d):  # noqa: F821
                            continue
                        t_key = key
                        t_hit = t
                        h_inst = inst
                        h_j = j
                        h_prim = tri_prim[j]
                        hb0 = b0
                        hb1 = b1
                        hb2 = b2
            # Pop the nearest pending box that can still hold a better hit.
            entry = 0
            found = False
            while sp > sp0:
                sp -= 1
                if stack_t[sp] <= t_key:
                    entry = stack_node[sp]
                    entry_key = stack_t[sp]
                    found = True
                    break
            if not found:
                return t_key, t_hit, h_inst, h_j, h_prim, hb0, hb1, hb2, cost

    return blas_closest


blas_closest = jit_inline(closest_traversal(False))


def any_hit_traversal(alpha: bool) -> Callable[..., tuple]:
    """:func:`blas_occluded`; with ``alpha`` its twin that passes through a hit the global
    ``hidden`` rejects (as :func:`closest_traversal`)."""

    def blas_occluded(node_bounds, node_child, tri_verts, root, o, d, t_max, stack_node, sp0, s,
                      inst):  # fmt: skip
        """Whether anything in one BVH (from ``root``) lies on ``o + t d``, ``t`` in
        (0, t_max); its triangles belong to instance ``inst`` of the scene ``s`` (read by the
        alpha test only). Uses the stack above ``sp0``. Returns ``(hit, cost)``."""
        ox, oy, oz = o
        ix, iy, iz, nx, ny, nz, kx, ky, kz, sx, sy, sz, okx, oky, okz = ray_setup(o, d)
        cost = 0
        sp = sp0
        entry = root
        while True:
            if entry >= 0:
                # An interior node: go on into the first box entered, keep the others.
                cost += 1
                entry, sp = enter_any(
                    node_bounds, node_child, entry, ox, oy, oz, ix, iy, iz, nx, ny, nz, t_max,
                    stack_node, sp,
                )  # fmt: skip
                if entry != NO_ENTRY:
                    continue
            else:
                v = -1 - entry
                for j in range(v >> 3, (v >> 3) + (v & 7)):
                    cost += 1
                    t, b0, b1, b2 = intersect_triangle(
                        tri_verts, j, okx, oky, okz, kx, ky, kz, sx, sy, sz, t_max
                    )
                    if t < t_max:
                        if alpha and hidden(s, inst, j, b0, b1, b2, o, d):  # noqa: F821
                            continue
                        return True, cost
            if sp == sp0:
                return False, cost
            sp -= 1
            entry = stack_node[sp]

    return blas_occluded


blas_occluded = jit_inline(any_hit_traversal(False))


@jit_inline
def intersect(node_bounds, node_child, tri_verts, tri_prim, o, d, t_max, stack_node, stack_t):
    """Closest hit of the ray ``o + t d``, ``t`` in (0, t_max), in one BVH.

    Returns ``(j, t, b0, b1, b2, cost)``: ``j`` the hit triangle's row (-1 for a miss),
    barycentrics of the hit, and the node visits plus triangle tests spent (a work measure).
    """
    _, t, _, j, _, b0, b1, b2, cost = blas_closest(
        node_bounds, node_child, tri_verts, tri_prim, 0, 0, 0.0, o, d, t_max, t_max,
        NO_INSTANCE, -1, NO_INSTANCE, 0.0, 0.0, 0.0, stack_node, stack_t, 0, None,
    )  # fmt: skip
    return j, t, b0, b1, b2, cost


@jit_inline
def occluded(node_bounds, node_child, tri_verts, o, d, t_max, stack_node):
    """Whether anything in one BVH lies on ``o + t d`` for ``t`` in (0, t_max): (hit, cost)."""
    return blas_occluded(node_bounds, node_child, tri_verts, 0, o, d, t_max, stack_node, 0, None, 0)


@jit_inline
def hit_point(tri_verts, j, b0, b1, b2):
    """Hit point from barycentrics, with a conservative bound on its absolute error per axis."""
    px = b0 * tri_verts[j, 0] + b1 * tri_verts[j, 3] + b2 * tri_verts[j, 6]
    py = b0 * tri_verts[j, 1] + b1 * tri_verts[j, 4] + b2 * tri_verts[j, 7]
    pz = b0 * tri_verts[j, 2] + b1 * tri_verts[j, 5] + b2 * tri_verts[j, 8]
    ex = GAMMA7 * (
        abs(b0 * tri_verts[j, 0]) + abs(b1 * tri_verts[j, 3]) + abs(b2 * tri_verts[j, 6])
    )
    ey = GAMMA7 * (
        abs(b0 * tri_verts[j, 1]) + abs(b1 * tri_verts[j, 4]) + abs(b2 * tri_verts[j, 7])
    )
    ez = GAMMA7 * (
        abs(b0 * tri_verts[j, 2]) + abs(b1 * tri_verts[j, 5]) + abs(b2 * tri_verts[j, 8])
    )
    return (px, py, pz), (ex, ey, ez)


@jit_inline
def geometric_normal(tri_verts, j):
    """Unit normal of triangle ``j`` by the right-hand rule (counter-clockwise front face)."""
    x0 = np.float64(tri_verts[j, 0])
    y0 = np.float64(tri_verts[j, 1])
    z0 = np.float64(tri_verts[j, 2])
    e1x = tri_verts[j, 3] - x0
    e1y = tri_verts[j, 4] - y0
    e1z = tri_verts[j, 5] - z0
    e2x = tri_verts[j, 6] - x0
    e2y = tri_verts[j, 7] - y0
    e2z = tri_verts[j, 8] - z0
    nx = e1y * e2z - e1z * e2y
    ny = e1z * e2x - e1x * e2z
    nz = e1x * e2y - e1y * e2x
    length = math.sqrt(nx * nx + ny * ny + nz * nz)
    return (nx / length, ny / length, nz / length), 0.5 * length


@jit
def offset_ray_origin(p, err, n, w):
    """Origin for a ray leaving ``p`` (error ``err``) in direction ``w``, past the error bound.

    Moves along the geometric normal ``n``, to the side ``w`` points to, by the projection of the
    error box onto ``n`` plus a margin covering the rounding of the move itself (pbrt-v4's
    OffsetRayOrigin rounds with nextafter instead; the margin is the same guarantee, cheaper).
    """
    dist = abs(n[0]) * err[0] + abs(n[1]) * err[1] + abs(n[2]) * err[2]
    magnitude = max(abs(p[0]), max(abs(p[1]), abs(p[2]))) + dist
    dist += OFFSET_ROUNDING_MARGIN * magnitude
    if n[0] * w[0] + n[1] * w[1] + n[2] * w[2] < 0.0:
        dist = -dist
    return (p[0] + dist * n[0], p[1] + dist * n[1], p[2] + dist * n[2])

"""Ray queries against a whole scene: the top-level BVH over instances, then each instance's
mesh BVH in object space (``tracer.geometry.intersect``), plus what shading needs at a hit.

Rays are world-space. Entering an instance maps the ray into object space with the inverse
transform; ``t`` keeps its meaning, because the direction is mapped without normalising.
Spawned rays start past the hit point's error bound *in object space*, widened by the error of
the round trip world -> object that the next traversal will make (``spawn``), so they cannot
re-hit their own surface however the instance is transformed.
"""

import math

import numpy as np

from tracer.compiled.arrays import pick
from tracer.geometry.intersect import (
    NO_ENTRY,
    NO_INSTANCE,
    OFFSET_ROUNDING_MARGIN,
    blas_closest,
    blas_occluded,
    enter_any,
    geometric_normal,
    hit_point,
    push_far,
    slab_setup,
    visit,
)
from tracer.geometry.transforms import apply_normal, apply_point, apply_vector
from tracer.kernel.jit import jit_inline

NO_SLAB = (0.0, 0.0, 0.0, 0, 0, 0)
"""Box-test constants of a scene without a top level (never read)."""
GUARD = 1.0 + 2.0**-20
"""Slack on magnitude bounds, so a bound taken before a tiny offset still covers the result."""


@jit_inline
def to_object(s, k, o, d):
    """The world ray (o, d) in instance ``k``'s object space."""
    if s.inst_identity[k]:
        return o, d
    return apply_point(s.inst_inv, k, o), apply_vector(s.inst_inv, k, d)


@jit_inline
def _leaf_range(c):
    v = -1 - c
    return v >> 3, (v >> 3) + (v & 7)


@jit_inline
def scene_closest(s, o, d, t_max, stack_node, stack_t):
    """Closest hit of the ray ``o + t d``, ``t`` in (0, t_max), in render space.

    Returns ``(k, j, t, b0, b1, b2, cost)``: instance ``k`` (-1 for a miss), the triangle's row
    ``j`` in the instance's pool, the distance, barycentrics and the work done.

    The top level is walked with one stack holding both nodes and leaves; a leaf entered
    becomes the run of instances ``tlas_inst[q:q_end]`` to visit, each entered with the leaf's
    key (``intersect.blas_closest`` explains keys: they make the hit independent of the order
    of the visits). A scene of one instance skips the top level.
    """
    t_key = t_max
    t_hit = t_max
    h_inst = NO_INSTANCE
    h_j = -1
    h_prim = NO_INSTANCE
    hb0 = 0.0
    hb1 = 0.0
    hb2 = 0.0
    cost = 0
    sp = 0
    q = 0
    q_end = 0
    entry = 0  # the top-level root
    entry_key = 0.0
    leaf_key = 0.0
    ix, iy, iz, nx, ny, nz = NO_SLAB
    if s.tlas_inst.shape[0] == 1:
        q_end = 1
        entry = NO_ENTRY
    else:  # the top level's box tests need the world ray's constants
        ix, iy, iz, nx, ny, nz = slab_setup(d)
    while True:
        if q < q_end:
            k = s.tlas_inst[q]
            q += 1
            pool = s.inst_pool[k]
            o_k, d_k = to_object(s, k, o, d)
            t_key, t_hit, h_inst, h_j, h_prim, hb0, hb1, hb2, c_blas = blas_closest(
                pick(s.blas_bounds, pool),
                pick(s.blas_child, pool),
                pick(s.tri_verts, pool),
                pick(s.tri_prim, pool),
                s.inst_root[k],
                k,
                leaf_key,
                o_k,
                d_k,
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
                sp,
                s,
            )
            cost += c_blas
            continue
        if entry >= 0:
            # A top-level node: go on into the nearest box entered, keep the others.
            cost += 1
            t0, c0, t1, c1, t2, c2, t3, c3 = visit(
                s.tlas_bounds, s.tlas_child, entry, o[0], o[1], o[2], ix, iy, iz, nx, ny, nz,
                entry_key, t_key,
            )  # fmt: skip
            sp = push_far(stack_node, stack_t, sp, t1, c1, t2, c2, t3, c3)
            if t0 < np.inf:
                entry = c0
                entry_key = t0
                continue
        elif entry != NO_ENTRY:
            q, q_end = _leaf_range(entry)
            leaf_key = entry_key
            entry = NO_ENTRY
            continue
        # Pop the nearest pending node or leaf that can still hold a better hit.
        entry = NO_ENTRY
        while sp > 0:
            sp -= 1
            if stack_t[sp] <= t_key:
                entry = stack_node[sp]
                entry_key = stack_t[sp]
                break
        if entry == NO_ENTRY:
            k_out = h_inst if h_inst != NO_INSTANCE else -1
            return k_out, h_j, t_hit, hb0, hb1, hb2, cost


@jit_inline
def scene_occluded(s, o, d, t_max, stack_node):
    """Whether anything lies on the ray ``o + t d``, ``t`` in (0, t_max): (hit, cost)."""
    cost = 0
    sp = 0
    q = 0
    q_end = 0
    entry = 0  # the top-level root
    ix, iy, iz, nx, ny, nz = NO_SLAB
    if s.tlas_inst.shape[0] == 1:
        q_end = 1
        entry = NO_ENTRY
    else:  # the top level's box tests need the world ray's constants
        ix, iy, iz, nx, ny, nz = slab_setup(d)
    while True:
        if q < q_end:
            k = s.tlas_inst[q]
            q += 1
            pool = s.inst_pool[k]
            o_k, d_k = to_object(s, k, o, d)
            blocked, c_blas = blas_occluded(
                pick(s.blas_bounds, pool),
                pick(s.blas_child, pool),
                pick(s.tri_verts, pool),
                s.inst_root[k],
                o_k,
                d_k,
                t_max,
                stack_node,
                sp,
                s,
                k,
            )
            cost += c_blas
            if blocked:
                return True, cost
            continue
        if entry == NO_ENTRY:
            if sp == 0:
                return False, cost
            sp -= 1
            entry = stack_node[sp]
        if entry < 0:
            q, q_end = _leaf_range(entry)
            entry = NO_ENTRY
            continue
        # A top-level node: go on into the first box entered, keep the others.
        cost += 1
        entry, sp = enter_any(
            s.tlas_bounds, s.tlas_child, entry, o[0], o[1], o[2], ix, iy, iz, nx, ny, nz, t_max,
            stack_node, sp,
        )  # fmt: skip


@jit_inline
def material_of(s, k, j):
    """Material index of row ``j`` of instance ``k``."""
    m = s.inst_material[k]
    if m < 0:
        m = pick(s.tri_material, s.inst_pool[k])[j]
    return m


@jit_inline
def object_of(s, k, j):
    """Scene node (object id) of row ``j`` of instance ``k``: the instance's own, or for a
    baked static mesh the node of the run (``static_runs``) that holds the row's triangle."""
    o = s.inst_object[k]
    if o >= 0:
        return o
    key = -1 - o + pick(s.tri_prim, s.inst_pool[k])[j]
    lo = 0
    hi = s.static_runs.shape[0]
    while hi - lo > 1:  # the last run starting at or before ``key``
        mid = (lo + hi) // 2
        if s.static_runs[mid, 0] <= key:
            lo = mid
        else:
            hi = mid
    return s.static_runs[lo, 1]


@jit_inline
def surface(s, k, j, b0, b1, b2):
    """A point of instance ``k``'s triangle ``j`` at barycentrics (b0, b1, b2).

    Returns ``(p_o, err_o, n_o, p_w, n_w)``: the object-space point, its error bound and unit
    normal (for spawning rays), and the world-space point and unit geometric normal (for shading).
    """
    tv = pick(s.tri_verts, s.inst_pool[k])
    p_o, err_o = hit_point(tv, j, b0, b1, b2)
    n_o, _ = geometric_normal(tv, j)
    if s.inst_identity[k]:
        return p_o, err_o, n_o, p_o, n_o
    n = apply_normal(s.inst_inv, k, n_o)
    inv_len = 1.0 / math.sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2])
    n_w = (n[0] * inv_len, n[1] * inv_len, n[2] * inv_len)
    return p_o, err_o, n_o, apply_point(s.inst_xform, k, p_o), n_w


@jit_inline
def shading_normal(s, k, j, b0, b1, b2, n_w):
    """The unit shading normal of instance ``k``'s triangle ``j`` at barycentrics (b0, b1, b2),
    world space, on the side of its geometric normal ``n_w``: ``(True, n)``, its vertex normals
    interpolated, or ``(False, n_w)`` where the triangle has none (a flat mesh, or normals that
    cancel)."""
    rows = pick(s.tri_normal, s.inst_pool[k])
    if rows.shape[0] == 0:
        return False, n_w
    x = b0 * rows[j, 0] + b1 * rows[j, 3] + b2 * rows[j, 6]
    y = b0 * rows[j, 1] + b1 * rows[j, 4] + b2 * rows[j, 7]
    z = b0 * rows[j, 2] + b1 * rows[j, 5] + b2 * rows[j, 8]
    n = (np.float64(x), np.float64(y), np.float64(z))
    if not s.inst_identity[k]:
        n = apply_normal(s.inst_inv, k, n)
    length2 = n[0] * n[0] + n[1] * n[1] + n[2] * n[2]
    if not length2 > 1e-24:
        return False, n_w
    inv_len = 1.0 / math.sqrt(length2)
    if n[0] * n_w[0] + n[1] * n_w[1] + n[2] * n_w[2] < 0.0:
        inv_len = -inv_len
    return True, (n[0] * inv_len, n[1] * inv_len, n[2] * inv_len)


@jit_inline
def offset_distance(s, k, p_o, err_o, n_o):
    """How far along the object normal ``n_o`` a ray leaving instance ``k``'s point ``p_o``
    (error ``err_o``) must start: past the point's error bound, past the error of mapping the
    origin to the world and back (``transforms.round_trip_bound``), and past the rounding of
    the move itself."""
    n_sum = abs(n_o[0]) + abs(n_o[1]) + abs(n_o[2])
    projected = abs(n_o[0]) * err_o[0] + abs(n_o[1]) * err_o[1] + abs(n_o[2]) * err_o[2]
    p_max = max(abs(p_o[0]) + err_o[0], max(abs(p_o[1]) + err_o[1], abs(p_o[2]) + err_o[2]))
    c1 = s.inst_rt[k, 0]
    c0 = s.inst_rt[k, 1]
    dist = projected + (c1 * p_max + c0) * n_sum
    # The round-trip bound must hold for the moved point too: take it once more, a bit wider.
    dist = projected + (c1 * (p_max + dist) * GUARD + c0) * n_sum
    return dist + OFFSET_ROUNDING_MARGIN * (p_max + dist)


@jit_inline
def spawn(s, k, p_o, n_o, dist, n_w, w):
    """World origin of a ray leaving instance ``k``'s surface point ``p_o`` toward the world
    direction ``w``: moved ``dist`` (``offset_distance``) along the object normal, to the side
    ``w`` points to (the sign of ``w`` against the world normal ``n_w`` decides it), then
    mapped to the world."""
    if n_w[0] * w[0] + n_w[1] * w[1] + n_w[2] * w[2] < 0.0:
        dist = -dist
    moved = (p_o[0] + dist * n_o[0], p_o[1] + dist * n_o[1], p_o[2] + dist * n_o[2])
    if s.inst_identity[k]:
        return moved
    return apply_point(s.inst_xform, k, moved)

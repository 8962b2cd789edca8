"""The light tree over a scene's emissive triangles (``tracer.shading.light_tree`` samples it).

Built top down as pbrt-v4's ``BVHLightSampler``: each node splits its triangles at the bucket
boundary of their centroids (12 buckets on each axis) that minimises the surface area
orientation heuristic, power times the orientation measure of the normal cone times the box's
surface area, over both sides. The cones and costs are computed exactly from the triangles of
each candidate side, with square roots and arithmetic only (no ``acos``: a polynomial stands in
for it in the cost), in a fixed order, so every CPU builds the same bits. The binary tree is
then collapsed into the 4-wide one the kernels walk (``_collapse``): a node's row holds its four
slots' bounds side by side, so one vector operation weighs all four.
"""

import weakref
from typing import NamedTuple

import numpy as np

from tracer.compiled.arrays import pick
from tracer.geometry.intersect import geometric_normal
from tracer.geometry.transforms import apply_normal, apply_point
from tracer.kernel.jit import jit
from tracer.shading.light_tree import (
    AXIS,
    CENTRE,
    COS_O,
    NODE,
    PHI,
    RADIUS2,
    SIN_O,
    TWO_SIDED,
    WIDTH,
)
from tracer.shading.lights import TRIANGLE, emission_mean

BUCKETS = 12
MAX_DEPTH = 63
"""Below this depth a binary node is split at its median, so no leaf lies deeper than 32 levels
of the 4-wide tree: trails of two bits a level fit 64 bits."""
EMPTY = np.iinfo(np.int32).min
"""``light_tree_child`` of an empty slot (its power is 0: never picked)."""


class LightTreeArrays(NamedTuple):
    """The ``SceneArrays`` fields of the tree (empty: no tree)."""

    light_tree_nodes: np.ndarray
    """float64 (N, ``light_tree.NODE * light_tree.WIDTH``): each node's slots, field by field
    (``tracer.shading.light_tree``); node 0 is the root."""
    light_tree_child: np.ndarray
    """int32 (N, ``light_tree.WIDTH``): each slot's node, ``-1 - light`` for a triangle, or
    ``EMPTY``."""
    light_tree_bits: np.ndarray
    """uint64 (T,): each triangle's path from the root (bits 2d and 2d + 1: its slot at
    depth d)."""
    light_tree_area: np.ndarray
    """float64 (T,): each triangle's area (render space)."""
    light_tree_keys: np.ndarray
    """int64 (T,): ``instance << 32 | pool row`` of each triangle, ascending."""
    light_tree_key_light: np.ndarray
    """int32 (T,): the triangle of each key."""


def empty_tree() -> LightTreeArrays:
    """No tree."""
    return LightTreeArrays(np.zeros((0, NODE * WIDTH)), np.zeros((0, WIDTH), np.int32),
                           np.zeros(0, np.uint64),
                           np.zeros(0), np.zeros(0, np.int64), np.zeros(0, np.int32))  # fmt: skip


_TREES: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
"""Each compiled scene's tree, built the first time a plan samples lights with it."""


def light_tree_of(scene) -> LightTreeArrays:
    """The light tree of a ``CompiledScene`` (built once, kept as long as the scene)."""
    tree = _TREES.get(scene)
    if tree is None:
        tree = _TREES[scene] = build_light_tree(scene.arrays)
    return tree


def build_light_tree(arrays) -> LightTreeArrays:
    """The tree over the emissive triangles of ``arrays`` (a ``SceneArrays``): the first
    entries of its light table."""
    count = int(np.count_nonzero(arrays.light_kind == TRIANGLE))
    if count == 0:
        return empty_tree()
    verts, normal, area, phi, two_sided = _triangles(
        arrays.tri_verts, arrays.inst_pool, arrays.inst_xform, arrays.inst_inv,
        arrays.inst_identity, arrays.light_inst[:count], arrays.light_tri[:count],
        arrays.inst_material, arrays.tri_material, arrays.mat_emission, arrays.mat_two_sided,
    )  # fmt: skip
    nodes, child, bits = _collapse(*_build(verts, normal, phi, two_sided), count)
    keys = (arrays.light_inst[:count].astype(np.int64) << 32) | arrays.light_tri[:count]
    order = np.argsort(keys, kind="stable")
    return LightTreeArrays(nodes, child, bits, area, keys[order], order.astype(np.int32))


@jit
def _triangles(tri_verts, inst_pool, xform, inv, identity, inst, tri, inst_material,
               tri_material, emission, two_sided):  # fmt: skip
    """Each light's render-space vertices (T, 9), unit normal (T, 3) as the kernel's
    ``sample_triangle`` computes it, area, power (mean emission times area) and
    two-sidedness."""
    t = inst.shape[0]
    verts = np.empty((t, 9))
    normal = np.empty((t, 3))
    area = np.empty(t)
    phi = np.empty(t)
    two = np.empty(t, np.bool_)
    for i in range(t):
        k = inst[i]
        j = tri[i]
        tv = pick(tri_verts, inst_pool[k])
        for c in range(3):
            q = (np.float64(tv[j, 3 * c]), np.float64(tv[j, 3 * c + 1]),
                 np.float64(tv[j, 3 * c + 2]))  # fmt: skip
            if not identity[k]:
                q = apply_point(xform, k, q)
            verts[i, 3 * c] = q[0]
            verts[i, 3 * c + 1] = q[1]
            verts[i, 3 * c + 2] = q[2]
        n_o, _ = geometric_normal(tv, j)
        n = n_o
        if not identity[k]:
            n = apply_normal(inv, k, n_o)
            inv_len = 1.0 / np.sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2])
            n = (n[0] * inv_len, n[1] * inv_len, n[2] * inv_len)
        normal[i, 0] = n[0]
        normal[i, 1] = n[1]
        normal[i, 2] = n[2]
        e1 = (verts[i, 3] - verts[i, 0], verts[i, 4] - verts[i, 1], verts[i, 5] - verts[i, 2])
        e2 = (verts[i, 6] - verts[i, 0], verts[i, 7] - verts[i, 1], verts[i, 8] - verts[i, 2])
        cx = e1[1] * e2[2] - e1[2] * e2[1]
        cy = e1[2] * e2[0] - e1[0] * e2[2]
        cz = e1[0] * e2[1] - e1[1] * e2[0]
        area[i] = 0.5 * np.sqrt(cx * cx + cy * cy + cz * cz)
        m = inst_material[k]
        if m < 0:
            m = pick(tri_material, inst_pool[k])[j]
        phi[i] = emission_mean(emission, m) * area[i]
        two[i] = two_sided[m]
    return verts, normal, area, phi, two


@jit
def _acos01(x):
    """acos(x) for x in [0, 1] to 7e-5 (Abramowitz and Stegun 4.4.45): the cost needs no more,
    and libm's ``acos`` may round differently on another CPU."""
    return np.sqrt(1.0 - x) * (1.5707288 + x * (-0.2121144 + x * (0.0742610 - 0.0187293 * x)))


@jit
def _orientation_measure(cos_o, sin_o):
    """pbrt-v4's M_Omega of a normal cone of half-angle theta_o widened by 90 degrees."""
    if cos_o >= 0.0:
        return 2.0 * np.pi - np.pi * cos_o + 0.5 * np.pi * np.pi * sin_o
    return 2.0 * np.pi * (1.0 - cos_o) + np.pi * _acos01(-cos_o) * sin_o


@jit
def _side(verts, normal, phi, two_sided, idx, start, end, bucket, b, left):
    """Bounds, normal cone, power and sidedness of the triangles idx[start:end] whose bucket is
    below ``b`` (``left``) or not: ``(lo, hi, axis, cos_o, phi, two_sided, count)``."""
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    sx = 0.0
    sy = 0.0
    sz = 0.0
    power = 0.0
    two = False
    count = 0
    for r in range(start, end):
        if (bucket[r - start] < b) != left:
            continue
        i = idx[r]
        count += 1
        for c in range(3):
            for a in range(3):
                x = verts[i, 3 * c + a]
                lo[a] = min(lo[a], x)
                hi[a] = max(hi[a], x)
        sx += normal[i, 0]
        sy += normal[i, 1]
        sz += normal[i, 2]
        power += phi[i]
        two = two or two_sided[i]
    length = np.sqrt(sx * sx + sy * sy + sz * sz)
    axis = np.array([0.0, 0.0, 1.0])
    cos_o = -1.0
    if length > 1e-9 * count:
        axis[0] = sx / length
        axis[1] = sy / length
        axis[2] = sz / length
        cos_o = 1.0
        for r in range(start, end):
            if (bucket[r - start] < b) != left:
                continue
            i = idx[r]
            d = axis[0] * normal[i, 0] + axis[1] * normal[i, 1] + axis[2] * normal[i, 2]
            cos_o = min(cos_o, d)
        cos_o = max(-1.0, cos_o)
    return lo, hi, axis, cos_o, power, two, count


@jit
def _cost(lo, hi, cos_o, power):
    ex = hi[0] - lo[0]
    ey = hi[1] - lo[1]
    ez = hi[2] - lo[2]
    area = 2.0 * (ex * ey + ey * ez + ez * ex)
    sin_o = np.sqrt(max(0.0, 1.0 - cos_o * cos_o))
    return power * _orientation_measure(cos_o, sin_o) * area


@jit
def _split(verts, normal, phi, two_sided, centroid, idx, tmp, bucket, start, end, depth, extent):
    """Partition idx[start:end] (stably) where the cost is least; returns the boundary."""
    count = end - start
    levels = 0
    while (1 << levels) < count:
        levels += 1
    best = np.inf
    best_axis = -1
    best_b = 0
    if depth + levels < MAX_DEPTH:
        widest = max(extent[0], max(extent[1], extent[2]))
        for axis in range(3):
            c_lo = np.inf
            c_hi = -np.inf
            for r in range(start, end):
                c_lo = min(c_lo, centroid[idx[r], axis])
                c_hi = max(c_hi, centroid[idx[r], axis])
            if not c_hi > c_lo:
                continue
            for r in range(start, end):
                k = int(BUCKETS * ((centroid[idx[r], axis] - c_lo) / (c_hi - c_lo)))
                bucket[r - start] = min(k, BUCKETS - 1)
            regular = widest / extent[axis]
            for b in range(1, BUCKETS):
                lo, hi, _, cos_o, power, _, n_left = _side(
                    verts, normal, phi, two_sided, idx, start, end, bucket, b, True
                )
                if n_left == 0 or n_left == count:
                    continue
                cost = _cost(lo, hi, cos_o, power)
                lo, hi, _, cos_o, power, _, _ = _side(
                    verts, normal, phi, two_sided, idx, start, end, bucket, b, False
                )
                cost = regular * (cost + _cost(lo, hi, cos_o, power))
                if cost < best:
                    best = cost
                    best_axis = axis
                    best_b = b
    if best_axis < 0:
        return start + count // 2  # the median, in the (deterministic) order idx has
    c_lo = np.inf
    c_hi = -np.inf
    for r in range(start, end):
        c_lo = min(c_lo, centroid[idx[r], best_axis])
        c_hi = max(c_hi, centroid[idx[r], best_axis])
    n_left = 0
    for r in range(start, end):
        k = min(BUCKETS - 1, int(BUCKETS * ((centroid[idx[r], best_axis] - c_lo) / (c_hi - c_lo))))
        if k < best_b:
            idx[start + n_left] = idx[r]
            n_left += 1
        else:
            tmp[r - start - n_left] = idx[r]
    for r in range(count - n_left):
        idx[start + n_left + r] = tmp[r]
    return start + n_left


@jit
def _push(stack, top, start, end, depth, parent, second):
    stack[top, 0] = start
    stack[top, 1] = end
    stack[top, 2] = depth
    stack[top, 3] = parent
    stack[top, 4] = second


@jit
def _build(verts, normal, phi, two_sided):
    """The binary tree over the triangles: its nodes (one row of ``NODE`` fields each) and
    their second children (``-1 - light`` for a leaf), in depth first order."""
    t = verts.shape[0]
    nodes = np.zeros((2 * t - 1, NODE))
    child = np.empty(2 * t - 1, np.int32)
    idx = np.arange(t)
    tmp = np.empty(t, np.int64)
    bucket = np.zeros(t, np.int64)
    centroid = np.empty((t, 3))
    for i in range(t):
        for a in range(3):
            centroid[i, a] = (verts[i, a] + verts[i, 3 + a] + verts[i, 6 + a]) / 3.0
    # A stack of ranges: (start, end, depth, parent, second child?).
    stack = np.empty((2 * MAX_DEPTH + 4, 5), np.int64)
    _push(stack, 0, 0, t, 0, -1, 0)
    top = 1
    next_id = 0
    while top > 0:
        top -= 1
        start = stack[top, 0]
        end = stack[top, 1]
        depth = stack[top, 2]
        parent = stack[top, 3]
        second = stack[top, 4]
        node = next_id
        next_id += 1
        if second:
            child[parent] = node
        lo, hi, axis, cos_o, power, two, _ = _side(
            verts, normal, phi, two_sided, idx, start, end, bucket, 0, False
        )
        r2 = 0.0
        for a in range(3):
            nodes[node, CENTRE + a] = 0.5 * (lo[a] + hi[a])
            r2 += 0.25 * (hi[a] - lo[a]) * (hi[a] - lo[a])
        nodes[node, RADIUS2] = r2
        nodes[node, AXIS : AXIS + 3] = axis
        nodes[node, COS_O] = cos_o
        nodes[node, SIN_O] = np.sqrt(max(0.0, 1.0 - cos_o * cos_o))
        nodes[node, PHI] = power
        nodes[node, TWO_SIDED] = 1.0 if two else 0.0
        if end - start == 1:
            child[node] = -1 - idx[start]
            continue
        mid = _split(verts, normal, phi, two_sided, centroid, idx, tmp, bucket, start, end,
                     depth, hi - lo)  # fmt: skip
        _push(stack, top, mid, end, depth + 1, node, 1)
        _push(stack, top + 1, start, mid, depth + 1, node, 0)
        top += 2
    return nodes, child


@jit
def _collapse(nodes, child, t):
    """The 4-wide tree of a binary one: a wide node's slots are a binary node's children,
    the inner one with the most power replaced by its two children while fewer than four;
    each triangle's trail, two bits (its slot) a level. Slots left over stay empty."""
    wide = np.zeros((max(t - 1, 1), NODE * WIDTH))
    wide_child = np.full((max(t - 1, 1), WIDTH), EMPTY, np.int32)
    bits = np.zeros(t, np.uint64)
    # A stack of binary nodes to make wide ones of: the wide node, its depth and trail.
    stack = np.zeros((MAX_DEPTH + 2) * WIDTH, np.int64)
    wide_of = np.zeros((MAX_DEPTH + 2) * WIDTH, np.int64)
    depth = np.zeros((MAX_DEPTH + 2) * WIDTH, np.int64)
    trails = np.zeros((MAX_DEPTH + 2) * WIDTH, np.uint64)
    slots = np.empty(WIDTH, np.int64)
    top = 1
    count = 1
    while top > 0:
        top -= 1
        b = stack[top]
        w = wide_of[top]
        level = depth[top]
        trail = trails[top]
        n = 1
        slots[0] = b  # a lone leaf at the root
        if child[b] >= 0:
            slots[0] = b + 1
            slots[1] = child[b]
            n = 2
        while n < WIDTH:
            best = -1
            for k in range(n):
                inner = child[slots[k]] >= 0
                if inner and (best < 0 or nodes[slots[k], PHI] > nodes[slots[best], PHI]):
                    best = k
            if best < 0:
                break
            split = slots[best]
            for k in range(n, best + 1, -1):
                slots[k] = slots[k - 1]
            slots[best] = split + 1
            slots[best + 1] = child[split]
            n += 1
        for k in range(n):
            s = slots[k]
            for f in range(NODE):
                wide[w, f * WIDTH + k] = nodes[s, f]
            slot_trail = trail | (np.uint64(k) << np.uint64(2 * level))
            if child[s] < 0:
                wide_child[w, k] = child[s]
                bits[-1 - child[s]] = slot_trail
            else:
                wide_child[w, k] = count
                stack[top] = s
                wide_of[top] = count
                depth[top] = level + 1
                trails[top] = slot_trail
                top += 1
                count += 1
    return wide[:count].copy(), wide_child[:count].copy(), bits

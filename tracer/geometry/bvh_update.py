"""Updating a mesh BVH whose vertices moved: refit, then rebuild the subtrees that degraded.

A refit keeps the tree and recomputes its boxes: cheap, but a tree built for one pose can be
poor for another (boxes that grew into each other). After a refit we measure each node's
*normalised SAH cost*, the expected cost of a ray that enters the node (Reiter, ch. 4):

    C(n) = (c_trav * A(n) + sum over children of C'(child)) / A(n),
    C'(interior child) = C(child) * A(child),  C'(leaf) = c_isect * count * A(leaf),

with A the half surface area of a box. It is scale-invariant: a mesh that only grows or
shrinks keeps its costs. Each node remembers its cost when it was last built; the topmost
nodes whose cost grew past ``threshold`` times that (Reiter: 1.3) have their subtree rebuilt
with the binned-SAH builder over the subtree's own triangles, and the tree is re-laid out.
``threshold = 0`` therefore always rebuilds the whole tree and ``threshold = inf`` only refits.

A subtree's triangles are one contiguous run of the leaf-ordered triangle array (the layout is
depth-first), so a rebuild only reorders triangles inside that run.
"""

import math
from typing import NamedTuple

import numpy as np

from tracer import config
from tracer.geometry import bvh as bvh_module
from tracer.geometry.bvh import WIDTH, TraversalBVH
from tracer.kernel.jit import jit


class BVHUpdate(NamedTuple):
    bvh: TraversalBVH
    reference: np.ndarray
    """float64 (N,): each node's normalised SAH cost when it was last built."""
    rebuilt_triangles: int
    rebuilt_subtrees: int


@jit
def _box_half_area(bounds, node, side):
    dx = np.float64(bounds[node, 12 + side]) - np.float64(bounds[node, side])
    dy = np.float64(bounds[node, 16 + side]) - np.float64(bounds[node, 4 + side])
    dz = np.float64(bounds[node, 20 + side]) - np.float64(bounds[node, 8 + side])
    if not (dx >= 0.0 and dy >= 0.0 and dz >= 0.0):
        return 0.0  # an empty (inverted) box
    return dx * dy + dy * dz + dz * dx


@jit
def _costs(node_bounds, node_child, c_trav, c_isect):
    """Per node: normalised SAH cost, and the run [first, end) of its triangles."""
    n = node_bounds.shape[0]
    weighted = np.empty(n, np.float64)  # C(n) * A(n)
    ratio = np.empty(n, np.float64)
    first = np.empty(n, np.int64)
    end = np.empty(n, np.int64)
    for node in range(n - 1, -1, -1):  # children come after their parent
        total = 0.0
        lo = np.int64(1) << 62
        hi = np.int64(-1)
        x0 = y0 = z0 = np.inf
        x1 = y1 = z1 = -np.inf
        for side in range(WIDTH):
            area = _box_half_area(node_bounds, node, side)
            if area > 0.0:
                x0 = min(x0, np.float64(node_bounds[node, side]))
                y0 = min(y0, np.float64(node_bounds[node, 4 + side]))
                z0 = min(z0, np.float64(node_bounds[node, 8 + side]))
                x1 = max(x1, np.float64(node_bounds[node, 12 + side]))
                y1 = max(y1, np.float64(node_bounds[node, 16 + side]))
                z1 = max(z1, np.float64(node_bounds[node, 20 + side]))
            c = node_child[node, side]
            if c >= 0:
                total += weighted[c]
                lo = min(lo, first[c])
                hi = max(hi, end[c])
            else:
                v = -1 - c
                count = v & 7
                if count > 0:
                    total += c_isect * count * area
                    lo = min(lo, np.int64(v >> 3))
                    hi = max(hi, np.int64((v >> 3) + count))
        dx, dy, dz = x1 - x0, y1 - y0, z1 - z0
        node_area = dx * dy + dy * dz + dz * dx if dx >= 0.0 else 0.0
        weighted[node] = c_trav * node_area + total
        ratio[node] = weighted[node] / node_area if node_area > 0.0 else c_trav
        first[node] = lo if hi >= 0 else 0
        end[node] = hi if hi >= 0 else 0
    return ratio, first, end


@jit
def _topmost_over(node_child, ratio, reference, threshold):
    """Nodes whose cost exceeds ``threshold`` x reference and no ancestor's does (DFS order)."""
    n = node_child.shape[0]
    marked = np.zeros(n, np.bool_)
    stack = np.empty(n + 1, np.int64)
    stack[0] = 0
    sp = 1
    while sp > 0:
        sp -= 1
        node = stack[sp]
        if ratio[node] > threshold * reference[node]:
            marked[node] = True
            continue
        for side in range(WIDTH):
            c = node_child[node, side]
            if c >= 0:
                stack[sp] = c
                sp += 1
    return marked


@jit
def _rebuild_marked(
    node_bounds, node_child, tri_verts, tri_prim, marked, first, end,
    n_bins, max_leaf, c_trav, c_isect, max_depth,
):  # fmt: skip
    """Rebuild every marked subtree over its own triangles and lay the tree out again,
    depth-first with children after parents. Returns the new arrays and, per new node, the
    old node it copies (-1 for a rebuilt one)."""
    n_old = node_bounds.shape[0]
    roots = np.flatnonzero(marked)
    budget = 0
    for r in roots:
        budget += max(1, end[r] - first[r])
    sub_bounds = np.empty((budget, 6 * WIDTH), np.float32)
    sub_child = np.empty((budget, WIDTH), np.int32)
    sub_start = np.full(n_old, -1, np.int64)  # old marked node -> its new subtree's root row
    out_verts = tri_verts.copy()
    out_prim = tri_prim.copy()
    used = 0
    for r in roots:
        t0 = first[r]
        t1 = end[r]
        local = np.ascontiguousarray(tri_verts[t0:t1])
        prims = np.arange(t1 - t0).astype(np.int32)
        lo, hi = bvh_module.triangle_bounds(local, prims)
        node_min, node_max, left_first, count, order = bvh_module._build(
            lo, hi, prims, n_bins, max_leaf, c_trav, c_isect, max_depth
        )
        b2, ch2, v, p = bvh_module._flatten(node_min, node_max, left_first, count, order, local)
        b, ch = bvh_module.collapse(b2, ch2, WIDTH)
        m = b.shape[0]
        for i in range(m):
            sub_bounds[used + i] = b[i]
            for side in range(WIDTH):
                c = ch[i, side]
                if c >= 0:
                    sub_child[used + i, side] = c + used
                else:
                    w = -1 - c
                    k = w & 7
                    f = (w >> 3) + (t0 if k > 0 else 0)
                    sub_child[used + i, side] = -1 - ((f << 3) | k)
        for i in range(t1 - t0):
            out_verts[t0 + i] = v[i]
            out_prim[t0 + i] = tri_prim[t0 + p[i]]
        sub_start[r] = used
        used += m

    # Lay out old (unmarked) and new nodes depth-first. A reference is (tree, row): tree 0 is
    # the old tree, tree 1 the rebuilt subtrees.
    capacity = n_old + used
    bounds = np.empty((capacity, 6 * WIDTH), np.float32)
    child = np.empty((capacity, WIDTH), np.int32)
    copied_from = np.full(capacity, -1, np.int64)
    st_tree = np.empty(capacity, np.int64)
    st_row = np.empty(capacity, np.int64)
    st_out = np.empty(capacity, np.int64)
    st_tree[0] = 0
    st_row[0] = 0
    st_out[0] = 0
    if marked[0]:
        st_tree[0] = 1
        st_row[0] = sub_start[0]
    sp = 1
    next_index = 1
    while sp > 0:
        sp -= 1
        tree = st_tree[sp]
        row = st_row[sp]
        out = st_out[sp]
        if tree == 0:
            bounds[out] = node_bounds[row]
            copied_from[out] = row
        else:
            bounds[out] = sub_bounds[row]
        for side in range(WIDTH):
            c = node_child[row, side] if tree == 0 else sub_child[row, side]
            if c < 0:
                child[out, side] = c
                continue
            child[out, side] = next_index
            st_out[sp] = next_index
            if tree == 0 and marked[c]:
                st_tree[sp] = 1
                st_row[sp] = sub_start[c]
            else:
                st_tree[sp] = tree
                st_row[sp] = c
            sp += 1
            next_index += 1
    return bounds[:next_index], child[:next_index], out_verts, out_prim, copied_from[:next_index]


def sah_costs(bvh: TraversalBVH) -> np.ndarray:
    """Normalised SAH cost of every node (float64 (N,))."""
    ratio, _, _ = _costs(
        bvh.node_bounds, bvh.node_child, config.BVH_TRAVERSAL_COST, config.BVH_INTERSECT_COST
    )
    return ratio


def rebuild(tri_verts: np.ndarray, tri_prim: np.ndarray) -> BVHUpdate:
    """A whole new tree over the triangles (leaf order in, composed ``tri_prim`` out)."""
    fresh = bvh_module.to_traversal(bvh_module.build(tri_verts), tri_verts)
    fresh = fresh._replace(tri_prim=tri_prim[fresh.tri_prim])
    return BVHUpdate(fresh, sah_costs(fresh), int(tri_verts.shape[0]), 1)


def update(
    bvh: TraversalBVH,
    tri_verts: np.ndarray,
    reference: np.ndarray,
    threshold: float = config.BVH_REBUILD_THRESHOLD,
) -> BVHUpdate:
    """``bvh`` over moved triangles (``tri_verts`` float32 (M, 9) in ``bvh``'s leaf order):
    refit, then rebuild the topmost subtrees whose normalised SAH cost grew past ``threshold``
    times ``reference`` (see the module docstring). ``bvh`` is left untouched."""
    if not threshold >= 0.0:
        raise ValueError(f"the rebuild threshold must be >= 0, got {threshold}")
    refitted = bvh_module.refit(bvh, tri_verts)
    if math.isinf(threshold):
        return BVHUpdate(refitted, reference, 0, 0)
    c_trav, c_isect = config.BVH_TRAVERSAL_COST, config.BVH_INTERSECT_COST
    ratio, first, end = _costs(refitted.node_bounds, refitted.node_child, c_trav, c_isect)
    marked = _topmost_over(refitted.node_child, ratio, reference, threshold)
    if marked[0]:
        return rebuild(refitted.tri_verts, refitted.tri_prim)
    if not marked.any():
        return BVHUpdate(refitted, reference, 0, 0)
    bounds, child, verts, prim, copied_from = _rebuild_marked(
        refitted.node_bounds,
        refitted.node_child,
        refitted.tri_verts,
        refitted.tri_prim,
        marked,
        first,
        end,
        config.BVH_BINS,
        config.BVH_MAX_LEAF,
        c_trav,
        c_isect,
        config.BVH_MAX_BUILD_DEPTH,
    )
    if bvh_module.stack_need(child) > bvh_module.MAX_STACK_NEED:
        return rebuild(refitted.tri_verts, refitted.tri_prim)
    result = TraversalBVH(bounds, child, verts, prim)
    new_reference = sah_costs(result)
    kept = copied_from >= 0
    new_reference[kept] = reference[copied_from[kept]]
    rebuilt = int((end[marked] - first[marked]).sum())
    return BVHUpdate(result, new_reference, rebuilt, int(marked.sum()))

"""Binned-SAH BVH: a deterministic builder and the traversal layout it is converted into.

Two layouts, after tinybvh:

``CanonicalBVH`` (what the builder writes)
    The Wald node: ``node_min``/``node_max`` (float32, (N, 3)), ``left_first`` and ``count``
    (int32, (N,)). ``count > 0``: a leaf over ``prim_order[left_first : left_first + count]``.
    ``count == 0``: an interior node whose children are ``left_first`` and ``left_first + 1``.
    Node 0 is the root. Empty leaves exist only as the root of an empty tree.

``TraversalBVH`` (what kernels read)
    A 4-wide tree collapsed from the binary one (as Embree's and tinybvh's BVH4 CPU layouts):
    interior nodes only, each holding the boxes of up to four children, so one visit tests four
    boxes. ``node_bounds`` float32 (N, 24), structure of arrays: row ``r`` of the box (min x,
    min y, min z, max x, max y, max z) of child slot ``s`` is at ``4 * r + s``.
    ``node_child`` int32 (N, 4): ``c >= 0`` is an interior node (after its parent); ``c < 0`` is
    a leaf, with ``v = -1 - c``, first triangle ``v >> 3`` and count ``v & 7`` (0 = an empty
    slot, with an inverted box). Triangles are stored in leaf order, depth first, so every
    subtree's triangles are one contiguous run: ``tri_verts`` float32 (M, 9) (v0, v1, v2) and
    ``tri_prim`` int32 (M,), the original triangle index of each. 112 bytes a node.

    The collapse opens, in each wide node, the interior child with the largest surface area
    until the node has four children. A traversal keeps at most ``stack_need`` entries of a
    tree on its stack; trees whose need exceeds ``MAX_STACK_NEED`` (only adversarial inputs)
    are kept binary (two slots a node), whose need the depth limit bounds.
"""

from typing import NamedTuple

import numpy as np

from tracer import config
from tracer.kernel.jit import jit

LEAF_COUNT_BITS = 3
MAX_TRIANGLES = (1 << (31 - LEAF_COUNT_BITS)) - 1
WIDTH = 4
"""Children per traversal node."""
NODE_FLOATS = 6 * WIDTH
MAX_STACK_NEED = (config.TRAVERSAL_STACK_SIZE - 4) // 2
"""Most stack entries one tree's traversal may need: a scene traversal stacks a mesh's on top
of the top level's, and each visit may write one entry past its last push."""


class CanonicalBVH(NamedTuple):
    node_min: np.ndarray
    node_max: np.ndarray
    left_first: np.ndarray
    count: np.ndarray
    prim_order: np.ndarray


class TraversalBVH(NamedTuple):
    node_bounds: np.ndarray
    node_child: np.ndarray
    tri_verts: np.ndarray
    tri_prim: np.ndarray

    @property
    def nbytes(self) -> int:
        """Bytes of node and triangle storage."""
        return sum(a.nbytes for a in self)


@jit
def _half_area(x0, y0, z0, x1, y1, z1):
    dx = x1 - x0
    dy = y1 - y0
    dz = z1 - z0
    return dx * dy + dy * dz + dz * dx


@jit
def triangle_bounds(tri_verts, prims):
    """Boxes of the triangles ``prims``: float32 (n, 3) min and max corners."""
    n = prims.shape[0]
    lo = np.empty((n, 3), np.float32)
    hi = np.empty((n, 3), np.float32)
    for i in range(n):
        p = prims[i]
        for a in range(3):
            x0 = tri_verts[p, a]
            x1 = tri_verts[p, 3 + a]
            x2 = tri_verts[p, 6 + a]
            lo[i, a] = min(x0, min(x1, x2))
            hi[i, a] = max(x0, max(x1, x2))
    return lo, hi


@jit
def _build(lo, hi, prims, n_bins, max_leaf, c_trav, c_isect, max_depth):
    n = prims.shape[0]
    cen = np.empty((n, 3), np.float64)
    for i in range(n):
        for a in range(3):
            cen[i, a] = 0.5 * (np.float64(lo[i, a]) + np.float64(hi[i, a]))
    order = np.arange(n).astype(np.int32)

    max_nodes = max(1, 2 * n - 1)
    node_min = np.empty((max_nodes, 3), np.float32)
    node_max = np.empty((max_nodes, 3), np.float32)
    left_first = np.zeros(max_nodes, np.int32)
    count = np.zeros(max_nodes, np.int32)
    if n == 0:
        node_min[0, :] = np.inf
        node_max[0, :] = -np.inf
        return node_min[:1], node_max[:1], left_first[:1], count[:1], order

    bin_count = np.zeros((3, n_bins), np.int64)
    bin_lo = np.empty((3, n_bins, 3), np.float64)
    bin_hi = np.empty((3, n_bins, 3), np.float64)
    right_area_count = np.empty(n_bins, np.float64)

    stack_size = 2 * (max_depth + 64)
    st_node = np.empty(stack_size, np.int64)
    st_start = np.empty(stack_size, np.int64)
    st_count = np.empty(stack_size, np.int64)
    st_depth = np.empty(stack_size, np.int64)
    sp = 0
    st_node[0] = 0
    st_start[0] = 0
    st_count[0] = n
    st_depth[0] = 0
    sp = 1
    n_nodes = 1
    cmin = np.empty(3, np.float64)
    cmax = np.empty(3, np.float64)
    axis_k = np.empty(3, np.float64)
    while sp > 0:
        sp -= 1
        node = st_node[sp]
        start = st_start[sp]
        cnt = st_count[sp]
        depth = st_depth[sp]

        # Bounds of the node's triangles and of their centroids.
        bx0 = np.inf
        by0 = np.inf
        bz0 = np.inf
        bx1 = -np.inf
        by1 = -np.inf
        bz1 = -np.inf
        for a in range(3):
            cmin[a] = np.inf
            cmax[a] = -np.inf
        for i in range(start, start + cnt):
            j = order[i]
            bx0 = min(bx0, lo[j, 0])
            by0 = min(by0, lo[j, 1])
            bz0 = min(bz0, lo[j, 2])
            bx1 = max(bx1, hi[j, 0])
            by1 = max(by1, hi[j, 1])
            bz1 = max(bz1, hi[j, 2])
            for a in range(3):
                cmin[a] = min(cmin[a], cen[j, a])
                cmax[a] = max(cmax[a], cen[j, a])
        node_min[node, 0] = bx0
        node_min[node, 1] = by0
        node_min[node, 2] = bz0
        node_max[node, 0] = bx1
        node_max[node, 1] = by1
        node_max[node, 2] = bz1

        if cnt <= 1:
            left_first[node] = start
            count[node] = cnt
            continue

        # Binned SAH over all three axes.
        best_cost = np.inf
        best_axis = -1
        best_split = -1
        if depth < max_depth:
            for a in range(3):
                extent = cmax[a] - cmin[a]
                axis_k[a] = n_bins / extent if extent > 0.0 else 0.0
                for b in range(n_bins):
                    bin_count[a, b] = 0
                    for c in range(3):
                        bin_lo[a, b, c] = np.inf
                        bin_hi[a, b, c] = -np.inf
            for i in range(start, start + cnt):
                j = order[i]
                l0 = lo[j, 0]
                l1 = lo[j, 1]
                l2 = lo[j, 2]
                h0 = hi[j, 0]
                h1 = hi[j, 1]
                h2 = hi[j, 2]
                for a in range(3):
                    b = int((cen[j, a] - cmin[a]) * axis_k[a])
                    if b >= n_bins:
                        b = n_bins - 1
                    bin_count[a, b] += 1
                    bin_lo[a, b, 0] = min(bin_lo[a, b, 0], l0)
                    bin_lo[a, b, 1] = min(bin_lo[a, b, 1], l1)
                    bin_lo[a, b, 2] = min(bin_lo[a, b, 2], l2)
                    bin_hi[a, b, 0] = max(bin_hi[a, b, 0], h0)
                    bin_hi[a, b, 1] = max(bin_hi[a, b, 1], h1)
                    bin_hi[a, b, 2] = max(bin_hi[a, b, 2], h2)
            for a in range(3):
                if axis_k[a] == 0.0:
                    continue
                # Sweep from the right: cost of the right side of split s (bins >= s).
                rx0 = np.inf
                ry0 = np.inf
                rz0 = np.inf
                rx1 = -np.inf
                ry1 = -np.inf
                rz1 = -np.inf
                rcount = 0
                for s in range(n_bins - 1, 0, -1):
                    if bin_count[a, s] > 0:
                        rx0 = min(rx0, bin_lo[a, s, 0])
                        ry0 = min(ry0, bin_lo[a, s, 1])
                        rz0 = min(rz0, bin_lo[a, s, 2])
                        rx1 = max(rx1, bin_hi[a, s, 0])
                        ry1 = max(ry1, bin_hi[a, s, 1])
                        rz1 = max(rz1, bin_hi[a, s, 2])
                        rcount += bin_count[a, s]
                    if rcount > 0:
                        right_area_count[s] = _half_area(rx0, ry0, rz0, rx1, ry1, rz1) * rcount
                    else:
                        right_area_count[s] = -1.0
                # Sweep from the left and combine.
                lx0 = np.inf
                ly0 = np.inf
                lz0 = np.inf
                lx1 = -np.inf
                ly1 = -np.inf
                lz1 = -np.inf
                lcount = 0
                for s in range(1, n_bins):
                    b = s - 1
                    if bin_count[a, b] > 0:
                        lx0 = min(lx0, bin_lo[a, b, 0])
                        ly0 = min(ly0, bin_lo[a, b, 1])
                        lz0 = min(lz0, bin_lo[a, b, 2])
                        lx1 = max(lx1, bin_hi[a, b, 0])
                        ly1 = max(ly1, bin_hi[a, b, 1])
                        lz1 = max(lz1, bin_hi[a, b, 2])
                        lcount += bin_count[a, b]
                    if lcount == 0 or right_area_count[s] < 0.0:
                        continue
                    cost = _half_area(lx0, ly0, lz0, lx1, ly1, lz1) * lcount + right_area_count[s]
                    if cost < best_cost:
                        best_cost = cost
                        best_axis = a
                        best_split = s

        parent_area = _half_area(bx0, by0, bz0, bx1, by1, bz1)
        if best_axis >= 0 and parent_area > 0.0:
            split_cost = c_trav + c_isect * best_cost / parent_area
        else:
            split_cost = c_trav
        if cnt <= max_leaf and (best_axis < 0 or split_cost >= c_isect * cnt):
            left_first[node] = start
            count[node] = cnt
            continue

        if best_axis >= 0:
            a = best_axis
            k = axis_k[a]
            i = start
            last = start + cnt - 1
            while i <= last:
                j = order[i]
                b = int((cen[j, a] - cmin[a]) * k)
                if b >= n_bins:
                    b = n_bins - 1
                if b < best_split:
                    i += 1
                else:
                    order[i] = order[last]
                    order[last] = j
                    last -= 1
            mid = i
        else:
            # No usable split plane (identical centroids, or too deep): split at the index median.
            mid = start + cnt // 2

        left = n_nodes
        n_nodes += 2
        left_first[node] = left
        count[node] = 0
        st_node[sp] = left + 1
        st_start[sp] = mid
        st_count[sp] = start + cnt - mid
        st_depth[sp] = depth + 1
        sp += 1
        st_node[sp] = left
        st_start[sp] = start
        st_count[sp] = mid - start
        st_depth[sp] = depth + 1
        sp += 1

    prim_order = np.empty(n, np.int32)
    for i in range(n):
        prim_order[i] = prims[order[i]]
    return (
        node_min[:n_nodes],
        node_max[:n_nodes],
        left_first[:n_nodes],
        count[:n_nodes],
        prim_order,
    )


@jit
def tree_depth(left_first, count):
    """Depth of a canonical tree (the root alone has depth 0); children follow their parent."""
    n = count.shape[0]
    depth = np.zeros(n, np.int64)
    deepest = 0
    for node in range(n):
        if count[node] == 0 and n > 1:
            depth[left_first[node]] = depth[node] + 1
            depth[left_first[node] + 1] = depth[node] + 1
        deepest = max(deepest, depth[node])
    return deepest


def build(tri_verts: np.ndarray, prims: np.ndarray | None = None) -> CanonicalBVH:
    """Build a canonical BVH over the triangles ``prims`` of ``tri_verts``.

    Parameters
    ----------
    tri_verts : float32 array, shape (T, 9)
        Vertices (v0, v1, v2) of each triangle; must be finite.
    prims : int32 array, shape (M,), optional
        The triangles to include (default: all). Degenerate triangles may be left out here.
    """
    tri_verts = np.ascontiguousarray(tri_verts, dtype=np.float32)
    if tri_verts.ndim != 2 or tri_verts.shape[1] != 9:
        raise ValueError(f"tri_verts must have shape (T, 9), got {tri_verts.shape}")
    if prims is None:
        prims = np.arange(tri_verts.shape[0], dtype=np.int32)
    prims = np.ascontiguousarray(prims, dtype=np.int32)
    lo, hi = triangle_bounds(tri_verts, prims)
    return build_boxes(lo, hi, prims)


def build_boxes(lo: np.ndarray, hi: np.ndarray, prims: np.ndarray) -> CanonicalBVH:
    """Build a canonical BVH over boxes ``lo``/``hi`` (float32, (M, 3)) named ``prims``."""
    if prims.shape[0] > MAX_TRIANGLES:
        raise ValueError(f"at most {MAX_TRIANGLES} primitives per BVH, got {prims.shape[0]}")
    if config.BVH_MAX_LEAF >= 1 << LEAF_COUNT_BITS:
        raise ValueError("BVH_MAX_LEAF does not fit the leaf encoding")
    result = CanonicalBVH(
        *_build(
            np.ascontiguousarray(lo, dtype=np.float32),
            np.ascontiguousarray(hi, dtype=np.float32),
            np.ascontiguousarray(prims, dtype=np.int32),
            config.BVH_BINS,
            config.BVH_MAX_LEAF,
            config.BVH_TRAVERSAL_COST,
            config.BVH_INTERSECT_COST,
            config.BVH_MAX_BUILD_DEPTH,
        )
    )
    leaves = result.count > 0
    if tree_depth(result.left_first, result.count) + 1 > config.BVH_MAX_TREE_DEPTH:
        raise AssertionError("BVH deeper than the traversal stack allows")
    if int(result.count.sum()) != prims.shape[0]:
        raise AssertionError("BVH leaves do not cover every primitive exactly once")
    if prims.shape[0] and int(leaves.sum()) * 2 - 1 != result.count.shape[0]:
        raise AssertionError("BVH node count is not 2 * leaves - 1")
    return result


@jit
def _flatten(node_min, node_max, left_first, count, prim_order, tri_verts):
    """The binary traversal tree (interior nodes only, both child boxes in one (N, 12) row,
    child references (N, 2)) that ``collapse`` makes wide, and the leaf-ordered triangles."""
    n_canon = count.shape[0]
    n_leaves = 0
    for i in range(n_canon):
        if count[i] > 0:
            n_leaves += 1
    n_int = max(1, n_canon - n_leaves)
    bounds = np.empty((n_int, 12), np.float32)
    child = np.empty((n_int, 2), np.int32)
    m = prim_order.shape[0]
    out_verts = np.empty((m, 9), np.float32)
    out_prim = np.empty(m, np.int32)

    if count[0] > 0 or n_canon == 1:
        # The root is a leaf (or the tree is empty): one node with the leaf left, an empty right.
        for c in range(3):
            bounds[0, c] = node_min[0, c]
            bounds[0, 3 + c] = node_max[0, c]
            bounds[0, 6 + c] = np.inf
            bounds[0, 9 + c] = -np.inf
        for i in range(m):
            out_prim[i] = prim_order[i]
            for c in range(9):
                out_verts[i, c] = tri_verts[prim_order[i], c]
        child[0, 0] = -1 - ((0 << 3) | count[0])
        child[0, 1] = -1
        return bounds, child, out_verts, out_prim

    stack_canon = np.empty(256, np.int64)
    stack_trav = np.empty(256, np.int64)
    sp = 1
    stack_canon[0] = 0
    stack_trav[0] = 0
    next_index = 1
    cursor = 0
    while sp > 0:
        sp -= 1
        c_node = stack_canon[sp]
        t_node = stack_trav[sp]
        first_child = left_first[c_node]
        for side in range(2):
            ch = first_child + side
            for c in range(3):
                bounds[t_node, 6 * side + c] = node_min[ch, c]
                bounds[t_node, 6 * side + 3 + c] = node_max[ch, c]
            k = count[ch]
            if k > 0:
                first = left_first[ch]
                for i in range(k):
                    p = prim_order[first + i]
                    out_prim[cursor + i] = p
                    for c in range(9):
                        out_verts[cursor + i, c] = tri_verts[p, c]
                child[t_node, side] = -1 - ((cursor << 3) | k)
                cursor += k
            else:
                child[t_node, side] = next_index
                stack_canon[sp] = ch
                stack_trav[sp] = next_index
                sp += 1
                next_index += 1
    return bounds, child, out_verts, out_prim


@jit
def _slot_area(node_bounds, node, side):
    """Half surface area of child ``side`` of a binary traversal node (-1 for an empty box)."""
    o = 6 * side
    dx = np.float64(node_bounds[node, o + 3]) - np.float64(node_bounds[node, o])
    dy = np.float64(node_bounds[node, o + 4]) - np.float64(node_bounds[node, o + 1])
    dz = np.float64(node_bounds[node, o + 5]) - np.float64(node_bounds[node, o + 2])
    if not dx >= 0.0:
        return -1.0
    return dx * dy + dy * dz + dz * dx


@jit
def collapse(node_bounds, node_child, width):
    """The wide layout (module docstring) of a binary traversal tree (``node_bounds`` (N, 12),
    ``node_child`` (N, 2), as ``_flatten`` writes): each wide node takes a binary node's two
    children and opens its largest interior child until it holds ``width`` (2 to 4) children.
    Nodes are laid out depth first, children after their parent; leaves are kept as they are."""
    n = node_bounds.shape[0]
    bounds = np.empty((n, NODE_FLOATS), np.float32)
    child = np.empty((n, WIDTH), np.int32)
    st_bin = np.empty(n + 1, np.int64)
    st_out = np.empty(n + 1, np.int64)
    st_bin[0] = 0
    st_out[0] = 0
    sp = 1
    n_out = 1
    slot_node = np.empty(WIDTH, np.int64)  # each slot is child ``slot_side`` of binary node
    slot_side = np.empty(WIDTH, np.int64)
    while sp > 0:
        sp -= 1
        b = st_bin[sp]
        out = st_out[sp]
        slot_node[0] = b
        slot_side[0] = 0
        slot_node[1] = b
        slot_side[1] = 1
        k = 2
        while k < width:
            best = -1
            best_area = -1.0
            for s in range(k):
                if node_child[slot_node[s], slot_side[s]] >= 0:
                    area = _slot_area(node_bounds, slot_node[s], slot_side[s])
                    if area > best_area:
                        best_area = area
                        best = s
            if best < 0:
                break
            c = node_child[slot_node[best], slot_side[best]]
            slot_node[best] = c
            slot_side[best] = 0
            slot_node[k] = c
            slot_side[k] = 1
            k += 1
        for s in range(WIDTH):
            if s < k:
                for r in range(6):
                    bounds[out, 4 * r + s] = node_bounds[slot_node[s], 6 * slot_side[s] + r]
                c = node_child[slot_node[s], slot_side[s]]
                if c >= 0:
                    child[out, s] = n_out
                    st_bin[sp] = c
                    st_out[sp] = n_out
                    sp += 1
                    n_out += 1
                else:
                    child[out, s] = c
            else:
                for r in range(3):
                    bounds[out, 4 * r + s] = np.inf
                    bounds[out, 4 * (r + 3) + s] = -np.inf
                child[out, s] = -1
    return bounds[:n_out].copy(), child[:n_out].copy()


@jit
def stack_need(node_child):
    """Most stack entries a traversal of this tree can hold: at each node it keeps every box
    it enters but one (the nearest, which it visits next), so a node adds its children but one
    to the need of its neediest interior child."""
    n = node_child.shape[0]
    need = np.zeros(n, np.int64)
    for node in range(n - 1, -1, -1):  # children come after their parent
        kids = 0
        deepest = 0
        for s in range(WIDTH):
            c = node_child[node, s]
            if c >= 0:
                kids += 1
                deepest = max(deepest, need[c])
            elif (-1 - c) & 7 > 0:
                kids += 1
        need[node] = max(kids - 1, 0) + deepest
    return need[0]


def flatten(canonical: CanonicalBVH, tri_verts: np.ndarray) -> TraversalBVH:
    """The traversal layout of a canonical tree, copying triangles into leaf order; four-wide,
    or two-wide when four-wide would need more than ``MAX_STACK_NEED`` stack entries."""
    bounds, child, verts, prim = _flatten(*canonical, tri_verts)
    for width in (WIDTH, 2):
        wide_bounds, wide_child = collapse(bounds, child, width)
        if stack_need(wide_child) <= MAX_STACK_NEED:
            return TraversalBVH(wide_bounds, wide_child, verts, prim)
    raise AssertionError("BVH traversal needs more stack than the kernels have")


def to_traversal(canonical: CanonicalBVH, tri_verts: np.ndarray) -> TraversalBVH:
    """Convert a canonical BVH into the traversal layout, copying triangles into leaf order."""
    result = flatten(canonical, np.ascontiguousarray(tri_verts, dtype=np.float32))
    refs = result.node_child[result.node_child < 0].astype(np.int64)
    if int((((-1 - refs) & 7) > 0).sum()) != int((canonical.count > 0).sum()):
        raise AssertionError("traversal BVH does not hold every leaf")
    return result


def decode_leaf(child: int) -> tuple[int, int]:
    """``(first, count)`` of a leaf child reference (``child < 0``)."""
    v = -1 - int(child)
    return v >> LEAF_COUNT_BITS, v & ((1 << LEAF_COUNT_BITS) - 1)


def slot_boxes(node_bounds: np.ndarray) -> np.ndarray:
    """The child boxes of traversal nodes as (N, WIDTH, 2, 3): node, slot, min/max, xyz."""
    return node_bounds.reshape(-1, 2, 3, WIDTH).transpose(0, 3, 1, 2)


@jit
def _refit(node_bounds, node_child, tri_verts):
    for node in range(node_bounds.shape[0] - 1, -1, -1):  # children come after their parent
        for s in range(WIDTH):
            c = node_child[node, s]
            lo0 = np.inf
            lo1 = np.inf
            lo2 = np.inf
            hi0 = -np.inf
            hi1 = -np.inf
            hi2 = -np.inf
            if c >= 0:
                for q in range(WIDTH):
                    lo0 = min(lo0, node_bounds[c, q])
                    lo1 = min(lo1, node_bounds[c, 4 + q])
                    lo2 = min(lo2, node_bounds[c, 8 + q])
                    hi0 = max(hi0, node_bounds[c, 12 + q])
                    hi1 = max(hi1, node_bounds[c, 16 + q])
                    hi2 = max(hi2, node_bounds[c, 20 + q])
            else:
                v = -1 - c
                for j in range(v >> 3, (v >> 3) + (v & 7)):
                    for q in range(3):
                        lo0 = min(lo0, tri_verts[j, 3 * q])
                        lo1 = min(lo1, tri_verts[j, 3 * q + 1])
                        lo2 = min(lo2, tri_verts[j, 3 * q + 2])
                        hi0 = max(hi0, tri_verts[j, 3 * q])
                        hi1 = max(hi1, tri_verts[j, 3 * q + 1])
                        hi2 = max(hi2, tri_verts[j, 3 * q + 2])
            node_bounds[node, s] = lo0
            node_bounds[node, 4 + s] = lo1
            node_bounds[node, 8 + s] = lo2
            node_bounds[node, 12 + s] = hi0
            node_bounds[node, 16 + s] = hi1
            node_bounds[node, 20 + s] = hi2


def refit(bvh: TraversalBVH, tri_verts: np.ndarray) -> TraversalBVH:
    """The same tree over moved triangles: ``tri_verts`` float32 (M, 9) replaces the rows of
    ``bvh.tri_verts`` (same leaf order); every box is recomputed bottom-up. Returns a new BVH
    and leaves ``bvh`` untouched."""
    tri_verts = np.ascontiguousarray(tri_verts, dtype=np.float32)
    if tri_verts.shape != bvh.tri_verts.shape:
        raise ValueError("refit needs the same number of triangles")
    bounds = bvh.node_bounds.copy()
    _refit(bounds, bvh.node_child, tri_verts)
    return TraversalBVH(bounds, bvh.node_child, tri_verts, bvh.tri_prim)

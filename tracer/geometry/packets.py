"""Closest hits of packets of ``PACKET`` rays: one traversal visits a node for all of them.

Each ray keeps what :func:`tracer.geometry.intersect.blas_closest` keeps for one ray: its best
hit and that hit's key, and for every box on the way its own key (its entry distance raised to
its parent's key; a stack row holds the ray's keys of a pending box). A ray is active in a box
while its key there is within its best key; a box is entered while any ray is active in it,
nearest first by the smallest key; a leaf tests each triangle against each active ray with
the scalar test. The single-ray kernel's hit is the least by (key, triangle) whatever the
order of the visits, so each ray of a packet gets the single-ray hit bit for bit.

Coherent rays (camera rays through neighbouring pixels) share most of their boxes, so a packet
does about one node visit where single rays do ``PACKET``; incoherent rays share little and
pay for the union of their paths (``docs/performance.md``).
"""

import numpy as np

from tracer.geometry.intersect import (
    NO_INSTANCE,
    _slab4,
    closer,
    intersect_triangle,
    nearest_first4,
    ray_setup,
)
from tracer.kernel.jit import jit_inline

PACKET = 4
"""Rays per packet."""


@jit_inline
def _push(stack_node, stack_key, sp, node, slot_keys, slot):
    """Push box ``slot`` (child ``node``) with every ray's key for it."""
    stack_node[sp] = node
    for r in range(PACKET):
        stack_key[sp, r] = slot_keys[slot, r]
    return sp + 1


@jit_inline
def packet_closest(
    node_bounds, node_child, tri_verts, tri_prim, origins, directions, t_max, i0, ray_f, ray_i,
    best_key, hit_t, hit_j, hit_b, entry_key, slot_keys, stack_node, stack_key,
):  # fmt: skip
    """Closest hits of rays ``i0 .. i0 + PACKET - 1`` of ``origins``/``directions`` in one BVH.

    Ray ``r``'s hit goes to ``hit_t[r]`` (``t_max`` for a miss), ``hit_j[r]`` (the triangle's
    row, -1 for a miss) and ``hit_b[r]`` (barycentrics). The other arrays are
    scratch: ``ray_f`` float64 (PACKET, 12), ``ray_i`` int64 (PACKET, 6), ``best_key`` and
    ``entry_key`` float64 (PACKET,), ``slot_keys`` float64 (4, PACKET), ``stack_key`` float64
    (stack size, PACKET). Returns the packet's work: node visits plus triangle tests (one per
    active ray).
    """
    for r in range(PACKET):
        i = i0 + r
        o = (origins[i, 0], origins[i, 1], origins[i, 2])
        d = (directions[i, 0], directions[i, 1], directions[i, 2])
        ix, iy, iz, nx, ny, nz, kx, ky, kz, sx, sy, sz, okx, oky, okz = ray_setup(o, d)
        floats = (ix, iy, iz, sx, sy, sz, okx, oky, okz, o[0], o[1], o[2])
        for k in range(12):
            ray_f[r, k] = floats[k]
        ints = (nx, ny, nz, kx, ky, kz)
        for k in range(6):
            ray_i[r, k] = ints[k]
        best_key[r] = t_max[i]
        hit_t[r] = t_max[i]
        hit_j[r] = -1
        entry_key[r] = 0.0
    work = 0
    sp = 0
    entry = 0
    while True:
        if entry >= 0:
            # An interior node: every active ray's keys for the four boxes, then the boxes
            # some ray enters, nearest first by their smallest key.
            work += 1
            m0 = np.inf
            m1 = np.inf
            m2 = np.inf
            m3 = np.inf
            for r in range(PACKET):
                t0 = np.inf
                t1 = np.inf
                t2 = np.inf
                t3 = np.inf
                floor = entry_key[r]
                if floor <= best_key[r]:
                    t0, t1, t2, t3 = _slab4(
                        node_bounds, entry, ray_i[r, 0], ray_i[r, 1], ray_i[r, 2], ray_f[r, 9],
                        ray_f[r, 10], ray_f[r, 11], ray_f[r, 0], ray_f[r, 1], ray_f[r, 2],
                        best_key[r],
                    )  # fmt: skip
                    t0 = max(t0, floor)
                    t1 = max(t1, floor)
                    t2 = max(t2, floor)
                    t3 = max(t3, floor)
                slot_keys[0, r] = t0
                slot_keys[1, r] = t1
                slot_keys[2, r] = t2
                slot_keys[3, r] = t3
                m0 = min(m0, t0)
                m1 = min(m1, t1)
                m2 = min(m2, t2)
                m3 = min(m3, t3)
            m0, s0, m1, s1, m2, s2, m3, s3 = nearest_first4(m0, 0, m1, 1, m2, 2, m3, 3)
            if m3 < np.inf:
                sp = _push(stack_node, stack_key, sp, node_child[entry, s3], slot_keys, s3)
            if m2 < np.inf:
                sp = _push(stack_node, stack_key, sp, node_child[entry, s2], slot_keys, s2)
            if m1 < np.inf:
                sp = _push(stack_node, stack_key, sp, node_child[entry, s1], slot_keys, s1)
            if m0 < np.inf:
                for r in range(PACKET):
                    entry_key[r] = slot_keys[s0, r]
                entry = node_child[entry, s0]
                continue
        else:
            v = -1 - entry
            for j in range(v >> 3, (v >> 3) + (v & 7)):
                for r in range(PACKET):
                    floor = entry_key[r]
                    if floor > best_key[r]:
                        continue
                    work += 1
                    t, b0, b1, b2 = intersect_triangle(
                        tri_verts, j, ray_f[r, 6], ray_f[r, 7], ray_f[r, 8], ray_i[r, 3],
                        ray_i[r, 4], ray_i[r, 5], ray_f[r, 3], ray_f[r, 4], ray_f[r, 5],
                        best_key[r],
                    )  # fmt: skip
                    if not t < np.inf:
                        continue
                    # The tie-break key of the best hit: (0, its triangle), or "no hit yet".
                    best_inst = NO_INSTANCE
                    best_prim = NO_INSTANCE
                    if hit_j[r] >= 0:
                        best_inst = 0
                        best_prim = tri_prim[hit_j[r]]
                    key = max(t, floor)
                    if closer(key, 0, tri_prim[j], best_key[r], best_inst, best_prim):
                        best_key[r] = key
                        hit_t[r] = t
                        hit_j[r] = j
                        hit_b[r, 0] = b0
                        hit_b[r, 1] = b1
                        hit_b[r, 2] = b2
        # Pop the nearest pending box in which some ray is still active.
        found = False
        while sp > 0:
            sp -= 1
            for r in range(PACKET):
                if stack_key[sp, r] <= best_key[r]:
                    found = True
            if found:
                entry = stack_node[sp]
                for r in range(PACKET):
                    entry_key[r] = stack_key[sp, r]
                break
        if not found:
            return work

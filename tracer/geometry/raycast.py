"""Batched ray queries over a BVH: closest hit and any hit for arrays of rays.

Used by the ray-casting benchmark, the robustness tests and single-ray queries. Rays are
interleaved over threads (``threads``, default every CPU); each answer depends only on the ray.
"""

from typing import NamedTuple

import numpy as np

from tracer import config
from tracer.geometry.bvh import TraversalBVH
from tracer.geometry.intersect import (
    geometric_normal,
    hit_point,
    intersect,
    occluded,
    offset_ray_origin,
)
from tracer.geometry.packets import PACKET, packet_closest
from tracer.kernel.borrow import borrowed
from tracer.kernel.jit import jit, jit_inline
from tracer.kernel.threads import run_parts

RAY_BLOCK = 256
"""Consecutive rays a thread takes before skipping to its next block (no false sharing)."""


class Hits(NamedTuple):
    """Closest hits: ``prim`` original triangle index (-1 for a miss), ``t`` distance (inf for a
    miss), barycentrics ``b`` (N, 3) of the hit, ``cost`` node visits plus triangle tests, and
    ``tri`` the hit's row in the BVH's leaf-ordered triangle arrays (-1 for a miss)."""

    prim: np.ndarray
    t: np.ndarray
    b: np.ndarray
    cost: np.ndarray
    tri: np.ndarray


@jit_inline
def _store_hit(i, j, t, b0, b1, b2, tri_prim, prim, t_out, bary, tri):
    """Ray ``i``'s hit of row ``j`` (nothing for a miss, ``j < 0``) into the output arrays."""
    if j >= 0:
        tri[i] = j
        prim[i] = tri_prim[j]
        t_out[i] = t
        bary[i, 0] = b0
        bary[i, 1] = b1
        bary[i, 2] = b2


@jit_inline
def _closest_one(
    node_bounds, node_child, tri_verts, tri_prim, origins, directions, t_max, i, stack_node,
    stack_t, prim, t_out, bary, cost, tri,
):  # fmt: skip
    """Ray ``i``'s closest hit, traced alone, into the output arrays."""
    o = (origins[i, 0], origins[i, 1], origins[i, 2])
    d = (directions[i, 0], directions[i, 1], directions[i, 2])
    j, t, b0, b1, b2, c = intersect(
        node_bounds, node_child, tri_verts, tri_prim, o, d, t_max[i], stack_node, stack_t
    )
    cost[i] = c
    _store_hit(i, j, t, b0, b1, b2, tri_prim, prim, t_out, bary, tri)


@jit
def _closest(
    node_bounds,
    node_child,
    tri_verts,
    tri_prim,
    origins,
    directions,
    t_max,
    first,
    stride,
    stack_node,
    stack_t,
    prim,
    t_out,
    bary,
    cost,
    tri,
):
    node_bounds = borrowed(node_bounds)
    node_child = borrowed(node_child)
    tri_verts = borrowed(tri_verts)
    tri_prim = borrowed(tri_prim)
    stack_node = borrowed(stack_node)
    stack_t = borrowed(stack_t)
    n = origins.shape[0]
    for block in range(first, (n + RAY_BLOCK - 1) // RAY_BLOCK, stride):
        for i in range(block * RAY_BLOCK, min(n, (block + 1) * RAY_BLOCK)):
            _closest_one(node_bounds, node_child, tri_verts, tri_prim, origins, directions, t_max,
                         i, stack_node, stack_t, prim, t_out, bary, cost, tri)  # fmt: skip


@jit
def _closest_packets(
    node_bounds,
    node_child,
    tri_verts,
    tri_prim,
    origins,
    directions,
    t_max,
    first,
    stride,
    stack_node,
    stack_t,
    prim,
    t_out,
    bary,
    cost,
    tri,
):
    """``_closest`` by packets of ``PACKET`` consecutive rays (a block's tail ray by ray)."""
    node_bounds = borrowed(node_bounds)
    node_child = borrowed(node_child)
    tri_verts = borrowed(tri_verts)
    tri_prim = borrowed(tri_prim)
    stack_node = borrowed(stack_node)
    stack_t = borrowed(stack_t)
    ray_f = np.empty((PACKET, 12))
    ray_i = np.empty((PACKET, 6), np.int64)
    best_key = np.empty(PACKET)
    hit_t = np.empty(PACKET)
    hit_j = np.empty(PACKET, np.int64)
    hit_b = np.zeros((PACKET, 3))
    entry_key = np.empty(PACKET)
    slot_keys = np.empty((4, PACKET))
    stack_key = np.empty((stack_node.shape[0], PACKET))
    n = origins.shape[0]
    for block in range(first, (n + RAY_BLOCK - 1) // RAY_BLOCK, stride):
        end = min(n, (block + 1) * RAY_BLOCK)
        i0 = block * RAY_BLOCK
        while i0 + PACKET <= end:
            cost[i0] = packet_closest(
                node_bounds, node_child, tri_verts, tri_prim, origins, directions, t_max, i0,
                ray_f, ray_i, best_key, hit_t, hit_j, hit_b, entry_key, slot_keys, stack_node,
                stack_key,
            )  # fmt: skip
            for r in range(PACKET):
                _store_hit(i0 + r, hit_j[r], hit_t[r], hit_b[r, 0], hit_b[r, 1], hit_b[r, 2],
                           tri_prim, prim, t_out, bary, tri)  # fmt: skip
            i0 += PACKET
        for i in range(i0, end):
            _closest_one(node_bounds, node_child, tri_verts, tri_prim, origins, directions, t_max,
                         i, stack_node, stack_t, prim, t_out, bary, cost, tri)  # fmt: skip


@jit
def _any(
    node_bounds, node_child, tri_verts, origins, directions, t_max, first, stride, stack_node, hit
):
    node_bounds = borrowed(node_bounds)
    node_child = borrowed(node_child)
    tri_verts = borrowed(tri_verts)
    stack_node = borrowed(stack_node)
    n = origins.shape[0]
    for block in range(first, (n + RAY_BLOCK - 1) // RAY_BLOCK, stride):
        for i in range(block * RAY_BLOCK, min(n, (block + 1) * RAY_BLOCK)):
            o = (origins[i, 0], origins[i, 1], origins[i, 2])
            d = (directions[i, 0], directions[i, 1], directions[i, 2])
            h, _ = occluded(node_bounds, node_child, tri_verts, o, d, t_max[i], stack_node)
            hit[i] = h


def _stacks() -> tuple[np.ndarray, np.ndarray]:
    """One thread's traversal stacks (node indices, entry distances)."""
    size = config.TRAVERSAL_STACK_SIZE
    return np.empty(size, np.int32), np.empty(size, np.float64)


def check_rays(origins, directions, t_max):
    # Contiguous and writeable: a read-only array would make numba compile another kernel.
    origins = np.require(origins, np.float64, ["C", "W"])
    directions = np.require(directions, np.float64, ["C", "W"])
    if origins.ndim != 2 or origins.shape[1] != 3 or directions.shape != origins.shape:
        raise ValueError("origins and directions must both have shape (N, 3)")
    if not (np.isfinite(origins).all() and np.isfinite(directions).all()):
        raise ValueError("ray origins and directions must be finite")
    if (np.abs(directions).max(axis=1, initial=0.0) == 0.0).any():
        raise ValueError("ray directions must be non-zero")
    if t_max is None:
        t_max = np.full(origins.shape[0], np.inf)
    t_max = np.array(np.broadcast_to(t_max, (origins.shape[0],)), dtype=np.float64)  # writeable
    if np.isnan(t_max).any():
        raise ValueError("t_max must not be NaN")
    return origins, directions, t_max


def closest_hits(
    bvh: TraversalBVH,
    origins: np.ndarray,
    directions: np.ndarray,
    t_max: np.ndarray | float | None = None,
    threads: int | None = None,
    packets: bool = False,
) -> Hits:
    """Closest hit of each ray ``origins[i] + t * directions[i]``, ``t`` in (0, t_max).

    With ``packets``, consecutive rays are traversed ``PACKET`` at a time
    (:mod:`tracer.geometry.packets`): the same hits bit for bit, faster where neighbouring rays
    are coherent (camera rays in pixel order), slower where they are not. ``cost`` then holds
    each packet's work on its first ray (its sum is still the work done).

    Parameters
    ----------
    origins, directions : float array, shape (N, 3)
        Directions need not be unit length; ``t`` is in units of the given direction.
    t_max : float or float array, shape (N,), optional
        Upper bound on ``t`` (default: no bound).
    """
    origins, directions, t_max = check_rays(origins, directions, t_max)
    n = origins.shape[0]
    hits = Hits(
        np.full(n, -1, np.int32),
        np.full(n, np.inf),
        np.zeros((n, 3)),
        np.zeros(n, np.int64),
        np.full(n, -1, np.int32),
    )
    args = (
        bvh.node_bounds,
        bvh.node_child,
        bvh.tri_verts,
        bvh.tri_prim,
        origins,
        directions,
        t_max,
    )
    kernel = _closest_packets if packets else _closest
    run_parts(lambda part, parts: kernel(*args, part, parts, *_stacks(), *hits), threads)
    return hits


def any_hits(
    bvh: TraversalBVH,
    origins: np.ndarray,
    directions: np.ndarray,
    t_max: np.ndarray | float | None = None,
    threads: int | None = None,
) -> np.ndarray:
    """Whether each ray meets any triangle for ``t`` in (0, t_max); bool array, shape (N,)."""
    origins, directions, t_max = check_rays(origins, directions, t_max)
    hit = np.zeros(origins.shape[0], np.bool_)
    args = (
        bvh.node_bounds,
        bvh.node_child,
        bvh.tri_verts,
        origins,
        directions,
        t_max,
    )
    run_parts(lambda part, parts: _any(*args, part, parts, _stacks()[0], hit), threads)
    return hit


@jit
def _surface(tri_verts, tri, bary, directions, points, errors, normals, origins):
    for i in range(tri.shape[0]):
        j = tri[i]
        if j < 0:
            continue
        p, err = hit_point(tri_verts, j, bary[i, 0], bary[i, 1], bary[i, 2])
        n, _ = geometric_normal(tri_verts, j)
        w = (directions[i, 0], directions[i, 1], directions[i, 2])
        o = offset_ray_origin(p, err, n, w)
        for c in range(3):
            points[i, c] = p[c]
            errors[i, c] = err[c]
            normals[i, c] = n[c]
            origins[i, c] = o[c]


class Surface(NamedTuple):
    """Where rays hit: ``point``, its conservative absolute ``error`` per axis, the unit
    geometric ``normal`` (counter-clockwise front), and ``origin``, the start of a ray leaving
    the point in the given direction, offset past the error (NaN rows for misses)."""

    point: np.ndarray
    error: np.ndarray
    normal: np.ndarray
    origin: np.ndarray


def surface(bvh: TraversalBVH, hits: Hits, directions: np.ndarray) -> Surface:
    """Hit points of ``hits`` and origins for rays leaving them along ``directions`` (N, 3).

    This is exactly how the path tracer spawns secondary and shadow rays.
    """
    n = hits.tri.shape[0]
    directions = np.array(np.broadcast_to(directions, (n, 3)), dtype=np.float64)  # writeable
    out = Surface(*(np.full((n, 3), np.nan) for _ in range(4)))
    _surface(bvh.tri_verts, hits.tri, hits.b, directions, *out)
    return out

"""Which static nodes are baked into one mesh: clusters whose float32 coordinates keep every
member's precision.

A baked mesh stores its triangles in float32 relative to one origin, so a node's rounding error
grows with its distance from that origin, not with its own size. One far object in a single
bake (a skybox card, a landmark) would move the origin away from the detailed geometry and
round it coarsely. So static nodes are grouped: a node joins a cluster only if its farthest
point from the cluster's origin is at most ``REACH`` times its own half size, so that it loses at
most log2(REACH) of float32's 24 bits against being baked alone (``docs/robustness.md``). Nodes
are taken largest first, each into the earliest founded cluster that can hold it, else it
founds one at its own (snapped) centre: the result depends only on the nodes, in a fixed order.
"""

from __future__ import annotations

import math

import numpy as np

REACH = 2.0**10
"""A member's farthest point from its cluster's origin, in half sizes of the member, at most."""


def snapped_center(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """The centre of the bounds, snapped to a power-of-two grid as coarse as their extent.

    Snapping leaves a mesh that already sits around its origin exactly where it is, and moves a
    distant one by an amount that float64 represents exactly at its scale.
    """
    center = 0.5 * (lo + hi)
    extent = float(np.max(hi - lo))
    if not extent > 0.0:
        return np.zeros(3)
    grid = 2.0 ** math.floor(math.log2(extent))
    return np.round(center / grid) * grid


def _level(length: float) -> int:
    """The power of two at or above ``length`` (> 0)."""
    return math.frexp(length)[1]


def cluster_nodes(lo: np.ndarray, hi: np.ndarray) -> list[list[int]]:
    """Clusters of the nodes with world bounds ``lo``, ``hi`` (float64 (N, 3)): lists of node
    indices, each ascending; the clusters in founding order."""
    half = 0.5 * np.max(hi - lo, axis=1)
    center = 0.5 * (lo + hi)
    reach = (REACH - 1.0) * half  # how far a node's centre may lie from its cluster's origin
    levels = sorted({_level(float(r)) for r in reach if r > 0.0})
    origins: list[np.ndarray] = []
    members: list[list[int]] = []
    grids: dict[tuple[int, int, int, int], list[int]] = {}  # (level, cell) -> clusters
    for i in sorted(range(len(half)), key=lambda i: (-half[i], i)):
        chosen = _find(grids, origins, center[i], float(reach[i])) if reach[i] > 0.0 else None
        if chosen is None:
            chosen = len(origins)
            origins.append(snapped_center(lo[i], hi[i]))
            members.append([])
            # Findable at every level a node searches at later (nodes only get smaller).
            top = _level(float(reach[i])) if reach[i] > 0.0 else levels[-1] if levels else 0
            for level in levels:
                if level <= top:
                    key = (level, *(int(c) for c in np.floor(origins[chosen] / 2.0**level)))
                    grids.setdefault(key, []).append(chosen)
        members[chosen].append(i)
    return [sorted(m) for m in members]


def _find(grids, origins, center: np.ndarray, reach: float) -> int | None:
    """The earliest founded cluster whose origin is within ``reach`` of ``center`` (per axis)."""
    level = _level(reach)  # cells at least ``reach`` wide: look in the 27 around the centre's
    cell = [int(c) for c in np.floor(center / 2.0**level)]
    candidates = sorted(
        k
        for dx in (-1, 0, 1)
        for dy in (-1, 0, 1)
        for dz in (-1, 0, 1)
        for k in grids.get((level, cell[0] + dx, cell[1] + dy, cell[2] + dz), ())
    )
    for k in candidates:
        if float(np.max(np.abs(center - origins[k]))) <= reach:
            return k
    return None

"""Spawned rays never hit their own surface, at any scale and far from the origin.

Hit points come from the real intersector (a ray shot at each triangle), and new rays leave them
exactly as the path tracer spawns them (``tracer.geometry.raycast.surface``: offset past the hit
point's error bound along the geometric normal). No epsilon is tuned per scene.
"""

import numpy as np
import pytest

from tracer import config
from tracer.geometry import bvh
from tracer.geometry.raycast import any_hits, closest_hits, surface

SCALES = [1e-4, 1e-2, 1.0, 1e2, 1e4, 1e5]
OFFSETS = [0.0, 1e2, 1e4, 1e6]


def random_triangles(rng, n: int, size: float, offset: float) -> np.ndarray:
    """``n`` random triangles of about ``size``, spread on a grid so none overlap, all shifted
    by ``offset`` along a random direction. float32, shape (n, 9)."""
    grid = np.stack(np.unravel_index(np.arange(n), (64, 64, 64)), axis=1) * 4.0 * size
    corners = grid[:, None, :] + rng.uniform(0.0, size, size=(n, 3, 3))
    shift = rng.normal(size=3)
    shift *= offset / np.linalg.norm(shift)
    return (corners + shift).reshape(n, 9).astype(np.float32)


def random_directions(rng, n: int) -> np.ndarray:
    d = rng.normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def hits_on_own_triangles(tri_verts, rng):
    """Shoot one ray at a random point of each triangle; returns (accel, hits)."""
    accel = bvh.to_traversal(bvh.build(tri_verts), tri_verts)
    n = tri_verts.shape[0]
    v = tri_verts.astype(np.float64).reshape(n, 3, 3)
    target = np.einsum("ij,ijk->ik", rng.dirichlet(np.ones(3), n), v)
    normal = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    side = np.where(rng.random(n) < 0.5, -1.0, 1.0)[:, None]
    size = np.abs(v - v.mean(axis=1, keepdims=True)).max(axis=(1, 2))[:, None]
    origin = target + side * normal * size + random_directions(rng, n) * 0.3 * size
    return accel, closest_hits(accel, origin, target - origin)


@pytest.mark.parametrize("offset", OFFSETS)
@pytest.mark.parametrize("scale", SCALES)
def test_spawned_rays_never_hit_their_own_triangle(scale, offset):
    if offset and scale < offset * 1e-4:
        pytest.skip("float32 cannot place a triangle this small this far out")
    rng = np.random.default_rng([SCALES.index(scale), OFFSETS.index(offset)])
    tri_verts = random_triangles(rng, 4096, scale, offset)
    accel, hits = hits_on_own_triangles(tri_verts, rng)
    hit = hits.prim >= 0
    assert hit.mean() > 0.9  # most aimed rays reach their triangle first
    for _ in range(4):  # many directions per point, into both half-spaces
        directions = random_directions(rng, len(hits.prim))
        spawned = surface(accel, hits, directions)
        again = closest_hits(accel, spawned.origin[hit], directions[hit])
        self_hits = int((again.prim == hits.prim[hit]).sum())
        assert self_hits == 0, f"{self_hits} spawned rays re-hit their own triangle"
        assert np.isfinite(spawned.origin[hit]).all()


@pytest.mark.parametrize(
    ("scale", "offset"), [(1e-3, 0.0), (1e-3, 0.1), (1.0, 0.0), (1.0, 100.0), (1e4, 1e6)]
)
def test_shadow_rays_between_close_surfaces_are_not_blocked(scale, offset):
    """Two parallel plates a relative 1e-4 apart (lower facing up, upper facing down): shadow
    rays from points on the lower plate to points on the upper one, with both ends offset as the
    integrator offsets them, are never occluded. (Offsets are kept where float32 can still
    represent the gap: the renderer recentres scenes, so world offsets never reach float32.)"""
    rng = np.random.default_rng(7)
    gap = 1e-4 * scale
    lower = np.array([[0, 0, 0], [0, 0, scale], [scale, 0, 0]], dtype=np.float64) + offset
    upper = lower[[0, 2, 1]] + np.array([0.0, gap, 0.0])
    tri_verts = np.stack([lower.reshape(9), upper.reshape(9)]).astype(np.float32)
    accel = bvh.to_traversal(bvh.build(tri_verts), tri_verts)
    v = tri_verts.astype(np.float64).reshape(2, 3, 3)
    n = 20_000
    up = np.array([0.0, 1.0, 0.0])

    def points_on(k):
        """Hit points on plate k, reached from between the plates."""
        target = (0.8 * rng.dirichlet(np.ones(3), n) + 0.2 / 3) @ v[k]
        middle = 0.5 * (v[0, 0, 1] + v[1, 0, 1])
        origin = target.copy()
        origin[:, 1] = middle
        hits = closest_hits(accel, origin, target - origin)
        assert np.all(hits.prim == k)
        return hits

    on_lower, on_upper = points_on(0), points_on(1)
    p = surface(accel, on_lower, up)
    q = surface(accel, on_upper, -up)
    p = surface(accel, on_lower, q.point - p.point)
    q = surface(accel, on_upper, p.point - q.point)
    blocked = any_hits(accel, p.origin, q.origin - p.origin, 1.0 - config.SHADOW_EPSILON)
    assert not blocked.any(), f"{int(blocked.sum())} of {n} shadow rays falsely occluded"

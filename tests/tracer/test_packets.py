"""Packet traversal gives every ray the single-ray traversal's closest hit, bit for bit."""

import numpy as np
import pytest

from tests.helpers import SOUP_KINDS, icosphere, rays_at, soup, traversal
from tracer.geometry.raycast import closest_hits


def _same_hits(bvh, origins, directions, t_max=None):
    single = closest_hits(bvh, origins, directions, t_max, threads=1)
    packed = closest_hits(bvh, origins, directions, t_max, threads=1, packets=True)
    for field in ("prim", "t", "b", "tri"):
        assert np.array_equal(getattr(single, field), getattr(packed, field)), field
    return single, packed


def _camera_rays(n_side: int, distance: float = 3.0):
    """A pinhole camera's rays in pixel order: neighbours in a packet are coherent."""
    u, v = np.meshgrid(np.linspace(-0.5, 0.5, n_side), np.linspace(-0.5, 0.5, n_side))
    directions = np.stack([u.ravel(), v.ravel(), np.ones(u.size)], axis=1)
    origins = np.tile([0.01, 0.02, -distance], (u.size, 1))
    return origins, directions


def test_coherent_rays_same_hits_and_less_work():
    """Camera rays over a sphere: the hits of the single-ray traversal, for less work (the
    packet's node visits are shared), and both hits and misses occur."""
    bvh = traversal(icosphere(4))
    origins, directions = _camera_rays(101)  # 10,201 rays: a tail that is not a whole packet
    single, packed = _same_hits(bvh, origins, directions)
    assert 0.2 < (single.prim >= 0).mean() < 0.9
    assert packed.cost.sum() < 0.8 * single.cost.sum()


@pytest.mark.parametrize("kind", SOUP_KINDS)
def test_incoherent_rays_and_finite_t_max_same_hits(kind):
    """Random rays (half aimed at triangles, half anywhere) through each kind of soup, with
    t_max finite for some: ties, slivers, coplanar and grid-aligned triangles included."""
    rng = np.random.default_rng(SOUP_KINDS.index(kind) + 40)
    tris = soup(rng, 2_000, kind)
    bvh = traversal(tris)
    origins, directions = rays_at(rng, tris, 3_001)
    t_max = np.where(rng.random(3_001) < 0.5, np.inf, rng.uniform(0.1, 2.0, 3_001))
    single, _ = _same_hits(bvh, origins, directions, t_max)
    assert (single.prim >= 0).any() and (single.prim < 0).any()


def test_rays_from_surfaces_same_hits():
    """Rays leaving a closed mesh's surface (the spawn offsets the renderer relies on) and rays
    along its triangles' edges toward shared vertices."""
    tris = icosphere(3)
    bvh = traversal(tris)
    v = tris.astype(np.float64).reshape(-1, 3, 3)
    rng = np.random.default_rng(3)
    k = rng.integers(0, len(v), 4_000)
    on_edge = 0.5 * (v[k, 0] + v[k, 1])
    origins = np.where(rng.random((4_000, 1)) < 0.5, on_edge, v[k, 2]) * 0.5
    directions = rng.normal(size=(4_000, 3))
    _same_hits(bvh, origins, directions)

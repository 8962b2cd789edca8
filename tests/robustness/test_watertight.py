"""Watertightness: a ray leaving the inside of a closed mesh always hits it.

Rays start inside and aim at random points on the surface, at the midpoints of every edge
(including the diagonals shared by the two triangles of a quad) and exactly at vertices: the
cases where a non-watertight test lets rays slip through shared edges. Properties, all exact:

* every ray hits something (it has to leave the closed solid somewhere);
* where the ray leaves the solid at its target, the hit is no later than the target
  (``t <= 1`` for direction ``target - origin``, up to the float64 rounding of ``t``): always
  for the cube (convex) and the icosphere seen from its centre (star-shaped), and for the Menger
  sponge wherever the point just past the target is outside the solid. (At a concave edge a ray
  can touch the surface and stay inside; then it correctly hits further on.)
"""

import numpy as np
import pytest
import trimesh

from tests.meshes import jittered_icosphere, menger_cells, menger_sponge
from tracer.geometry import bvh
from tracer.geometry.raycast import closest_hits

T_TOLERANCE = 1e-12


def build(vertices, faces):
    tri_verts = np.asarray(vertices, dtype=np.float64)[faces].reshape(-1, 9).astype(np.float32)
    return bvh.to_traversal(bvh.build(tri_verts), tri_verts), tri_verts


def surface_targets(tri_verts: np.ndarray, n_random: int, rng) -> dict[str, np.ndarray]:
    """Random surface points, every edge midpoint and every vertex, in float64 (all exact
    functions of the float32 vertices, so they lie on the stored surface)."""
    v = tri_verts.astype(np.float64).reshape(-1, 3, 3)
    pick = rng.integers(0, len(v), n_random)
    b = rng.dirichlet(np.ones(3), n_random)
    edges = np.concatenate([(v[:, i] + v[:, (i + 1) % 3]) / 2 for i in range(3)])
    return {
        "random points": np.einsum("ij,ijk->ik", b, v[pick]),
        "edge midpoints": np.unique(edges, axis=0),
        "vertices": np.unique(v.reshape(-1, 3), axis=0),
    }


def cast(accel, origins, targets, exits_at_target, label) -> int:
    """Assert the properties above; returns the number of rays cast."""
    hits = closest_hits(accel, origins, targets - origins)
    missed = int((hits.prim < 0).sum())
    assert missed == 0, f"{label}: {missed} of {len(origins)} rays slipped through"
    late = int((hits.t[exits_at_target] > 1.0 + T_TOLERANCE).sum())
    assert late == 0, f"{label}: {late} rays passed their target without a hit"
    return len(origins)


@pytest.fixture(scope="module")
def counter():
    return {"rays": 0}


def test_jittered_icosphere(counter):
    """From the centre every ray crosses the (star-shaped) surface once, at its target."""
    rng = np.random.default_rng(1)
    accel, tri_verts = build(*jittered_icosphere(subdivisions=5, jitter=0.05, seed=2))
    for kind, targets in surface_targets(tri_verts, 400_000, rng).items():
        origins = np.zeros_like(targets)
        everywhere = np.ones(len(targets), dtype=bool)
        counter["rays"] += cast(accel, origins, targets, everywhere, f"icosphere, {kind}")


def test_cube(counter):
    """Random origins inside a cube, aimed at its faces, edges, diagonals and corners."""
    rng = np.random.default_rng(3)
    mesh = trimesh.creation.box(extents=(2.0, 2.0, 2.0))
    accel, tri_verts = build(mesh.vertices, mesh.faces)
    repeats = {"random points": 1, "edge midpoints": 5_000, "vertices": 10_000}
    for kind, targets in surface_targets(tri_verts, 50_000, rng).items():
        targets = np.repeat(targets, repeats[kind], axis=0)
        origins = rng.uniform(-0.999, 0.999, size=targets.shape)
        everywhere = np.ones(len(targets), dtype=bool)
        counter["rays"] += cast(accel, origins, targets, everywhere, f"cube, {kind}")


def test_menger_sponge(counter):
    """Origins inside random solid cells of a level-3 sponge (36,096 triangles)."""
    level = 3
    side = 3**level
    rng = np.random.default_rng(4)
    accel, tri_verts = build(*menger_sponge(level))
    cells = menger_cells(level)
    solid = np.zeros((side, side, side), dtype=bool)
    solid[tuple(cells.T)] = True

    def outside(points: np.ndarray) -> np.ndarray:
        cell = np.floor(points * side).astype(np.int64)
        inside_box = np.all((cell >= 0) & (cell < side), axis=1)
        result = np.ones(len(points), dtype=bool)
        c = cell[inside_box]
        result[inside_box] = ~solid[c[:, 0], c[:, 1], c[:, 2]]
        return result

    repeats = {"random points": 1, "edge midpoints": 2, "vertices": 8}
    for kind, targets in surface_targets(tri_verts, 300_000, rng).items():
        targets = np.repeat(targets, repeats[kind], axis=0)
        origins = (cells[rng.integers(0, len(cells), len(targets))] + 0.5) / side
        origins += rng.uniform(-0.45, 0.45, size=origins.shape) / side
        beyond = targets + 1e-6 * (targets - origins) / np.linalg.norm(
            targets - origins, axis=1, keepdims=True
        )
        exits = outside(beyond) if kind != "random points" else np.ones(len(targets), bool)
        counter["rays"] += cast(accel, origins, targets, exits, f"Menger sponge, {kind}")


def test_at_least_a_million_rays_were_cast(counter):
    """The three tests above together cast at least 10^6 rays."""
    assert counter["rays"] >= 1_000_000, counter

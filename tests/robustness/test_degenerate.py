"""Degenerate geometry and degenerate rays: never a NaN, never a hit on a zero-area triangle,
the same answer every run; BVHs over pathological inputs build with bounded depth."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tests import naive
from tracer import config
from tracer.compiled.scene import STATIC_KEY, compile_scene
from tracer.geometry import bvh
from tracer.geometry.query import scene_hits
from tracer.geometry.raycast import any_hits, closest_hits
from tracer.scene.format import Camera, DiffuseMaterial, RenderSettings
from tracer.scene.loader import MeshData, SceneData


def accelerate(tri_verts):
    tri_verts = np.asarray(tri_verts, dtype=np.float32).reshape(-1, 9)
    return bvh.to_traversal(bvh.build(tri_verts), tri_verts)


def random_rays(rng, n, lo=-2.0, hi=2.0):
    o = rng.uniform(lo, hi, size=(n, 3))
    d = rng.normal(size=(n, 3))
    return o, d


def degenerate_soup(rng, n):
    """Zero-area triangles: repeated vertices, collinear vertices, a point. Coordinates are
    multiples of 1/16, so the collinear ones stay exactly collinear in float32."""
    a = rng.integers(-32, 32, size=(n, 3)) / 16.0
    b = rng.integers(-32, 32, size=(n, 3)) / 16.0
    kinds = [
        np.concatenate([a, a, b], axis=1),  # two equal vertices
        np.concatenate([a, b, b], axis=1),
        np.concatenate([a, a, a], axis=1),  # a point
        np.concatenate([a, 0.5 * (a + b), b], axis=1),  # collinear (midpoint)
        np.concatenate([a, b, 2.0 * b - a], axis=1),  # collinear (beyond)
        np.concatenate([a, a + [1.0, 0, 0], a + [3.0, 0, 0]], axis=1),  # axis-aligned line
    ]
    return np.concatenate(kinds).astype(np.float32)


def degenerate_scene(rng):
    """A scene of one valid triangle per object plus many zero-area ones, through the loader."""
    soup = degenerate_soup(rng, 200).reshape(-1, 3, 3).astype(np.float64)
    good = np.array([[[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [0.0, 1.0, 0.0]]])
    tris = np.concatenate([soup, good])
    vertices = tris.reshape(-1, 3)
    faces = np.arange(len(vertices)).reshape(-1, 3)
    data = SceneData(
        camera=Camera(position=(0, 0, 4), look_at=(0, 0, 0), width=16, height=16),
        render=RenderSettings(spp=2),
        material_names=["m"],
        materials=[DiffuseMaterial(emission=(1.0, 1.0, 1.0))],
        meshes=[MeshData("soup", vertices, faces, 0)],
    )
    return compile_scene(data), len(soup)


def test_zero_area_triangles_are_dropped_and_never_hit():
    rng = np.random.default_rng(0)
    scene, n_degenerate = degenerate_scene(rng)
    assert scene.stats.degenerate_triangles == n_degenerate
    good_prim = n_degenerate
    assert set(scene.meshes[STATIC_KEY].bvh.tri_prim.tolist()) == {good_prim}
    o, d = random_rays(rng, 100_000)
    hits = scene_hits(scene, o, d)
    assert set(np.unique(hits.triangle).tolist()) <= {-1, good_prim}
    assert not np.isnan(hits.t).any()


def test_zero_area_triangles_in_a_raw_bvh_report_no_hits():
    """Even handed straight to the BVH (no loader), exact repeats give det = 0: no hit."""
    rng = np.random.default_rng(1)
    soup = degenerate_soup(rng, 500)[:1500]  # the repeated-vertex and point kinds
    o, d = random_rays(rng, 50_000)
    hits = closest_hits(accelerate(soup), o, d)
    assert (hits.prim < 0).all()


@settings(max_examples=60, deadline=None)
@given(
    thinness=st.floats(1e-12, 1e-3),
    length=st.floats(1e-3, 1e3),
    seed=st.integers(0, 2**31),
)
def test_slivers_never_give_nan(thinness, length, seed):
    """Long thin triangles: no NaN; every reported hit is a valid point of the triangle, at the
    ray's ``t``; the answer is the same on every run."""
    rng = np.random.default_rng(seed)
    a = rng.uniform(-1, 1, 3) * length
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    side = np.cross(axis, rng.normal(size=3))
    side /= np.linalg.norm(side)
    tri = np.concatenate([a, a + axis * length, a + 0.5 * axis * length + side * thinness * length])
    tri_verts = tri.astype(np.float32)[None, :]
    accel = accelerate(tri_verts)
    o = rng.uniform(-2, 2, size=(2000, 3)) * length
    target = tri_verts.reshape(3, 3).astype(np.float64).mean(axis=0)
    d = target + rng.normal(size=(2000, 3)) * thinness * length - o
    hits = closest_hits(accel, o, d)
    assert not np.isnan(hits.t).any() and not np.isnan(hits.b).any()
    hit = hits.prim >= 0
    assert np.all(hits.t[hit] > 0.0) and np.all(np.isfinite(hits.t[hit]))
    assert np.all(hits.b[hit] >= 0.0) and np.allclose(hits.b[hit].sum(axis=1), 1.0)
    point = hits.b[hit] @ tri_verts.reshape(3, 3).astype(np.float64)
    along_ray = o[hit] + hits.t[hit, None] * d[hit]
    extent = np.abs(o[hit]).max(axis=1, keepdims=True) + np.abs(point).max(axis=1, keepdims=True)
    assert np.all(np.abs(point - along_ray) <= 1e-6 * extent)
    again = closest_hits(accel, o, d, threads=1)
    assert np.array_equal(again.prim, hits.prim) and np.array_equal(again.t, hits.t)


def test_coplanar_overlapping_triangles_are_deterministic():
    """Overlapping coplanar triangles: the same triangle and t every run and any thread count."""
    rng = np.random.default_rng(2)
    base = np.array([[-1, -1, 0], [1, -1, 0], [0, 1, 0]], dtype=np.float64)
    copies = [base + [rng.uniform(-0.2, 0.2), rng.uniform(-0.2, 0.2), 0] for _ in range(16)]
    accel = accelerate(np.stack(copies).reshape(-1, 9))
    o = np.concatenate([rng.uniform(-1, 1, (20_000, 2)), np.full((20_000, 1), 3.0)], axis=1)
    d = np.tile([0.0, 0.0, -1.0], (20_000, 1)) + rng.normal(size=(20_000, 3)) * 0.05
    first = closest_hits(accel, o, d, threads=1)
    for threads in (1, 2):
        again = closest_hits(accel, o, d, threads=threads)
        assert np.array_equal(first.prim, again.prim)
        assert np.array_equal(first.t, again.t)
    hit = first.prim >= 0
    np.testing.assert_allclose(first.t[hit], (3.0 / -d[hit, 2]), rtol=1e-12)


@pytest.mark.parametrize("sign", [0.0, -0.0])
def test_zero_and_negative_zero_direction_components(sign):
    """Axis-aligned rays (other components +0.0 or -0.0) hit an axis-aligned cube exactly."""
    import trimesh

    cube = trimesh.creation.box(extents=(2, 2, 2))
    accel = accelerate(cube.vertices[cube.faces].reshape(-1, 9))
    rng = np.random.default_rng(3)
    for axis in range(3):
        for direction in (1.0, -1.0):
            n = 5_000
            d = np.full((n, 3), sign)
            d[:, axis] = direction
            o = rng.uniform(-0.99, 0.99, size=(n, 3))
            o[:, axis] = -3.0 * direction
            hits = closest_hits(accel, o, d)
            assert (hits.prim >= 0).all()
            np.testing.assert_allclose(hits.t, 2.0, rtol=1e-12)
            # Rays starting exactly on a face plane of the cube's box, parallel to it.
            o2 = o.copy()
            other = (axis + 1) % 3
            o2[:, other] = 1.0
            hits2 = closest_hits(accel, o2, d)
            assert not np.isnan(hits2.t).any()


def test_rays_parallel_to_a_triangle_plane():
    """Rays in or parallel to a triangle's plane: no NaN, and no hit from a ray that lies off
    the plane."""
    tri = np.array([[-1, -1, 0], [1, -1, 0], [0, 1, 0]], dtype=np.float32).reshape(1, 9)
    accel = accelerate(tri)
    rng = np.random.default_rng(4)
    n = 20_000
    d = np.concatenate([rng.normal(size=(n, 2)), np.zeros((n, 1))], axis=1)
    in_plane = np.concatenate([rng.uniform(-2, 2, (n, 2)), np.zeros((n, 1))], axis=1)
    above = in_plane + [0.0, 0.0, 1e-7]
    for o in (in_plane, above):
        hits = closest_hits(accel, o, d)
        assert not np.isnan(hits.t).any()
    assert (closest_hits(accel, above, d).prim < 0).all()
    assert not any_hits(accel, above, d).any()


def test_grazing_rays_agree_with_the_oracle():
    """Rays at 1e-6 to 1e-2 radians from a large triangle's plane."""
    tri = np.array([[-10, 0, -10], [10, 0, -10], [0, 0, 10]], dtype=np.float32).reshape(1, 9)
    accel = accelerate(tri)
    rng = np.random.default_rng(5)
    n = 50_000
    angle = 10 ** rng.uniform(-6, -2, n)
    heading = rng.uniform(0, 2 * np.pi, n)
    d = np.stack([np.cos(heading), -np.sin(angle), np.sin(heading)], axis=1)
    target = np.concatenate(
        [rng.uniform(-3, 3, (n, 1)), np.zeros((n, 1)), rng.uniform(-3, 3, (n, 1))], axis=1
    )
    o = target - d * rng.uniform(0.5, 5.0, (n, 1))
    hits = closest_hits(accel, o, d)
    assert (hits.prim == 0).all()
    naive.assert_closest_match(hits, naive.closest_hits(tri, o, d))


@pytest.mark.parametrize(
    "name",
    ["identical centroids", "one plane", "one triangle", "no triangles"],
)
def test_bvh_builds_on_pathological_inputs(name):
    rng = np.random.default_rng(6)
    if name == "identical centroids":
        n = 100_000
        u = rng.normal(size=(n, 3, 3))
        tris = u - u.mean(axis=1, keepdims=True)  # every centroid at the origin
    elif name == "one plane":
        n = 100_000
        tris = rng.uniform(-1, 1, size=(n, 3, 3))
        tris[:, :, 2] = 0.25
    elif name == "one triangle":
        tris = np.array([[[-1, -1, 0], [1, -1, 0], [0, 1, 0]]], dtype=np.float64)
    else:
        tris = np.zeros((0, 3, 3))
    tri_verts = tris.reshape(-1, 9).astype(np.float32)
    canonical = bvh.build(tri_verts)
    assert int(canonical.count.sum()) == len(tri_verts)
    assert canonical.count.max(initial=0) <= config.BVH_MAX_LEAF
    accel = bvh.to_traversal(canonical, tri_verts)
    depth = tree_depth(canonical)
    assert depth <= config.TRAVERSAL_STACK_SIZE, depth
    o, d = random_rays(rng, 300)
    hits = closest_hits(accel, o, d)
    naive.assert_closest_match(hits, naive.closest_hits(tri_verts, o, d), max_ambiguous=0.05)


def tree_depth(canonical) -> int:
    depth = np.zeros(len(canonical.count), dtype=np.int64)
    deepest = 0
    for node in range(len(canonical.count)):  # children are always after their parent
        if canonical.count[node] == 0 and len(canonical.count) > 1:
            left = canonical.left_first[node]
            depth[left] = depth[left + 1] = depth[node] + 1
        deepest = max(deepest, int(depth[node]))
    return deepest

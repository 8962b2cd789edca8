"""Refit and selective rebuild of a deformed mesh BVH (tracer.geometry.bvh_update)."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tests.meshes import jittered_icosphere
from tracer import config
from tracer.geometry import bvh, bvh_update
from tracer.geometry.raycast import closest_hits


def icosphere_triangles(subdivisions: int = 3, seed: int = 0) -> np.ndarray:
    vertices, faces = jittered_icosphere(subdivisions, 0.05, seed)
    return vertices[faces].reshape(-1, 9).astype(np.float32), vertices, faces


def built(tri_verts: np.ndarray) -> tuple[bvh.TraversalBVH, np.ndarray]:
    tree = bvh.to_traversal(bvh.build(tri_verts), tri_verts)
    return tree, bvh_update.sah_costs(tree)


def check_tree(tree: bvh.TraversalBVH, triangles: np.ndarray) -> None:
    """A tree over ``triangles`` (mesh order): leaf rows are those triangles, each exactly once,
    every stored box contains what is below it, children come after their parents."""
    m = triangles.shape[0]
    assert np.array_equal(np.sort(tree.tri_prim), np.arange(m))
    assert np.array_equal(tree.tri_verts, triangles[tree.tri_prim])
    child = tree.node_child.astype(np.int64)
    boxes = bvh.slot_boxes(tree.node_bounds)  # (node, slot, min/max, xyz)
    inner = child >= 0
    node_of = np.broadcast_to(np.arange(child.shape[0])[:, None], child.shape)
    assert (child[inner] > node_of[inner]).all()
    assert np.array_equal(
        np.bincount(child[inner], minlength=child.shape[0])[1:], np.ones(child.shape[0] - 1)
    ), "every node but the root has exactly one parent"
    outer, kid = boxes[inner], boxes[child[inner]]
    assert (outer[:, None, 0] <= kid[:, :, 0]).all() and (kid[:, :, 1] <= outer[:, None, 1]).all()
    covered = np.zeros(m, np.int64)
    for box, c in zip(boxes[~inner], child[~inner], strict=True):
        first, count = bvh.decode_leaf(c)
        covered[first : first + count] += 1
        points = tree.tri_verts[first : first + count].reshape(-1, 3)
        assert (box[0] <= points).all() and (points <= box[1]).all()
    assert (covered == 1).all()


def random_rays(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    origins = rng.normal(size=(n, 3)) * 3.0
    targets = rng.normal(size=(n, 3)) * 0.8
    return origins, targets - origins


def scramble(vertices: np.ndarray, seed: int, fraction: float) -> np.ndarray:
    """Swap a fraction of the vertices with each other: long thin triangles across the mesh,
    the kind of deformation that ruins a refitted tree."""
    rng = np.random.default_rng(seed)
    moved = vertices.copy()
    pick = rng.choice(len(vertices), size=max(2, int(fraction * len(vertices))), replace=False)
    moved[pick] = vertices[rng.permutation(pick)]
    return moved


def test_infinite_threshold_is_a_refit():
    tri, vertices, faces = icosphere_triangles()
    tree, reference = built(tri)
    moved = (scramble(vertices, 1, 0.2)[faces]).reshape(-1, 9).astype(np.float32)
    leaf_order = moved[tree.tri_prim]
    result = bvh_update.update(tree, leaf_order, reference, math.inf)
    refit = bvh.refit(tree, leaf_order)
    assert result.rebuilt_triangles == 0
    assert all(np.array_equal(a, b) for a, b in zip(result.bvh, refit, strict=True))


def test_zero_threshold_rebuilds_everything():
    tri, vertices, faces = icosphere_triangles()
    tree, reference = built(tri)
    moved = (1.5 * vertices[faces]).reshape(-1, 9).astype(np.float32)
    result = bvh_update.update(tree, moved[tree.tri_prim], reference, 0.0)
    assert result.rebuilt_triangles == tri.shape[0]
    check_tree(result.bvh, moved)


def test_scaling_and_moving_a_mesh_rebuilds_nothing():
    """The normalised SAH cost is scale invariant: a uniformly scaled and moved mesh keeps its
    tree (scale by a power of two and shift by a float32-exact amount, so boxes scale exactly)."""
    tri, vertices, faces = icosphere_triangles()
    tree, reference = built(tri)
    moved = (4.0 * vertices[faces] + 2.0).reshape(-1, 9).astype(np.float32)
    result = bvh_update.update(tree, moved[tree.tri_prim], reference)
    assert result.rebuilt_triangles == 0
    np.testing.assert_allclose(bvh_update.sah_costs(result.bvh), reference, rtol=1e-5)


def test_local_deformation_rebuilds_only_degraded_subtrees_and_lowers_cost():
    """Scramble the vertices of a small cap of the sphere among themselves: the subtrees over
    the cap degrade, the rest of the tree does not."""
    tri, vertices, faces = icosphere_triangles(4)
    tree, reference = built(tri)
    cap = np.flatnonzero(vertices[:, 0] > 0.95)
    current = vertices.copy()
    current[cap] = vertices[np.random.default_rng(2).permutation(cap)]
    moved = (current[faces]).reshape(-1, 9).astype(np.float32)
    leaf_order = moved[tree.tri_prim]
    refit = bvh_update.update(tree, leaf_order, reference, math.inf)
    selective = bvh_update.update(tree, leaf_order, reference)
    assert 0 < selective.rebuilt_triangles < tri.shape[0]
    check_tree(selective.bvh, moved)
    refit_cost = bvh_update.sah_costs(refit.bvh)[0]
    selective_cost = bvh_update.sah_costs(selective.bvh)[0]
    assert selective_cost < refit_cost
    assert selective.reference.shape[0] == selective.bvh.node_bounds.shape[0]


@settings(max_examples=25)
@given(
    seed=st.integers(0, 2**16),
    fraction=st.sampled_from([0.0, 0.01, 0.05, 0.3]),
    noise=st.sampled_from([0.0, 0.01, 0.3]),
    threshold=st.sampled_from([0.0, 1.0, 1.1, config.BVH_REBUILD_THRESHOLD, 2.0, math.inf]),
    steps=st.integers(1, 3),
)
def test_updated_tree_is_valid_and_hits_what_a_fresh_tree_hits(
    seed, fraction, noise, threshold, steps
):
    """Through several deformation steps: a valid tree over the moved triangles, whose closest
    hits equal those of a tree built from scratch (bit for bit: triangle and distance)."""
    tri, vertices, faces = icosphere_triangles(2, seed)
    tree, reference = built(tri)
    rng = np.random.default_rng(seed)
    for step in range(steps):
        current = scramble(vertices, seed + step, fraction) if fraction else vertices
        current = current + rng.normal(scale=noise, size=current.shape)
        moved = current[faces].reshape(-1, 9).astype(np.float32)
        result = bvh_update.update(tree, moved[tree.tri_prim], reference, threshold)
        tree, reference = result.bvh, result.reference
        check_tree(tree, moved)
        assert reference.shape[0] == tree.node_bounds.shape[0]
    fresh, _ = built(moved)
    origins, directions = random_rays(2000, seed)
    a = closest_hits(tree, origins, directions, threads=1)
    b = closest_hits(fresh, origins, directions, threads=1)
    assert np.array_equal(a.prim, b.prim)
    assert np.array_equal(a.t, b.t)


def test_update_is_deterministic_and_leaves_its_input_alone():
    tri, vertices, faces = icosphere_triangles(3)
    tree, reference = built(tri)
    before = [a.copy() for a in tree]
    moved = (scramble(vertices, 3, 0.05)[faces]).reshape(-1, 9).astype(np.float32)
    first = bvh_update.update(tree, moved[tree.tri_prim], reference)
    second = bvh_update.update(tree, moved[tree.tri_prim], reference)
    assert all(np.array_equal(a, b) for a, b in zip(first.bvh, second.bvh, strict=True))
    assert np.array_equal(first.reference, second.reference)
    assert all(np.array_equal(a, b) for a, b in zip(tree, before, strict=True))


def test_negative_threshold_is_refused():
    tri, _, _ = icosphere_triangles(1)
    tree, reference = built(tri)
    with pytest.raises(ValueError, match="threshold"):
        bvh_update.update(tree, tree.tri_verts, reference, -1.0)

"""The BVH builder and its traversal layout: structure, bounds, coverage, depth, determinism.

Every property is checked on both layouts (``tracer.geometry.bvh`` docstring): the canonical Wald
nodes the builder writes and the two-boxes-per-node nodes the kernels read.
"""

import math
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tests.helpers import ROOT, SOUP_KINDS, box, icosphere, soup
from tracer import config
from tracer.geometry import bvh


def depth_bound(n: int) -> int:
    """Deepest leaf the builder may make (``tracer.config``): SAH down to the depth cap, then
    index-median splits, each halving a node until it fits in a leaf."""
    return config.BVH_MAX_BUILD_DEPTH + math.ceil(math.log2(max(n, 1)))


def tri_bounds(tri_verts: np.ndarray, order: np.ndarray, first, count):
    """Exact float32 bounds (lo, hi), each (L, 3), of the triangle ranges
    ``order[first : first + count]`` (non-empty, disjoint, covering ``order``)."""
    points = tri_verts[order].reshape(-1, 3, 3)
    t_lo, t_hi = points.min(axis=1), points.max(axis=1)
    sort = np.argsort(first)
    lo = np.empty((len(first), 3), np.float32)
    hi = np.empty((len(first), 3), np.float32)
    lo[sort] = np.minimum.reduceat(t_lo, first[sort], axis=0)
    hi[sort] = np.maximum.reduceat(t_hi, first[sort], axis=0)
    return lo, hi


def covers_once(first: np.ndarray, count: np.ndarray, m: int) -> bool:
    """Whether the ranges [first, first + count) partition [0, m)."""
    if (first < 0).any() or (first + count > m).any():
        return False
    index = (
        np.repeat(first, count)
        + np.arange(count.sum())
        - np.repeat(np.cumsum(count) - count, count)
    )
    return bool((np.bincount(index, minlength=m) == 1).all())


def depths(children) -> int:
    """Depth of a tree given, level by level, ``children(nodes) -> child nodes``."""
    depth, frontier = 0, np.array([0])
    while True:
        frontier = children(frontier)
        if frontier.size == 0:
            return depth
        depth += 1


def check_canonical(c: bvh.CanonicalBVH, tri_verts: np.ndarray, prims: np.ndarray) -> int:
    """Assert the canonical BVH's invariants; returns its depth (root = 0)."""
    n_nodes, m = c.count.shape[0], prims.shape[0]
    assert c.node_min.shape == c.node_max.shape == (n_nodes, 3)
    assert c.node_min.dtype == c.node_max.dtype == np.float32
    assert c.left_first.dtype == c.count.dtype == c.prim_order.dtype == np.int32
    assert np.array_equal(np.sort(c.prim_order), np.sort(prims)), "leaves do not hold `prims`"
    if m == 0:
        assert n_nodes == 1 and c.count[0] == 0
        assert (c.node_min[0] > c.node_max[0]).all(), "an empty root must have an inverted box"
        return 0

    leaf = c.count > 0
    inner = np.flatnonzero(~leaf)
    left = c.left_first[inner].astype(np.int64)
    # Children come after their parent and every node but the root has exactly one parent:
    # then the nodes form one tree rooted at 0, each reachable exactly once.
    assert (left > inner).all() and (left + 1 < n_nodes).all()
    parents = np.bincount(np.concatenate([left, left + 1]), minlength=n_nodes)
    assert parents[0] == 0 and (parents[1:] == 1).all(), "not a tree rooted at node 0"
    assert n_nodes == 2 * int(leaf.sum()) - 1

    # Interior boxes contain, and are exactly, the union of their children's boxes.
    for kid in (left, left + 1):
        assert (c.node_min[inner] <= c.node_min[kid]).all()
        assert (c.node_max[kid] <= c.node_max[inner]).all()
    assert np.array_equal(c.node_min[inner], np.minimum(c.node_min[left], c.node_min[left + 1]))
    assert np.array_equal(c.node_max[inner], np.maximum(c.node_max[left], c.node_max[left + 1]))

    # Leaves: at most BVH_MAX_LEAF triangles, ranges partitioning prim_order, tight boxes.
    first, count = c.left_first[leaf].astype(np.int64), c.count[leaf].astype(np.int64)
    assert count.max() <= config.BVH_MAX_LEAF, f"a leaf holds {count.max()} triangles"
    assert covers_once(first, count, m), "leaf ranges do not partition prim_order"
    lo, hi = tri_bounds(tri_verts, c.prim_order, first, count)
    assert (c.node_min[leaf] <= lo).all() and (hi <= c.node_max[leaf]).all(), "leaf box too small"
    assert np.array_equal(c.node_min[leaf], lo) and np.array_equal(c.node_max[leaf], hi)

    def children(nodes):
        nodes = nodes[~leaf[nodes]]
        return np.concatenate([c.left_first[nodes], c.left_first[nodes] + 1])

    depth = depths(children)
    assert depth <= depth_bound(m), f"depth {depth} for {m} triangles"
    return depth


def traversal_stack_need(t: bvh.TraversalBVH) -> int:
    """Peak stack entries of a traversal that enters every box: at a node, the pending entries
    of its ancestors plus its own children but the one it goes on into."""
    peak = 0
    frontier = np.array([0])
    pending = np.array([0])
    while frontier.size:
        child = t.node_child[frontier]
        used = (child >= 0) | (((-1 - child) & 7) > 0)
        k = used.sum(axis=1)
        pending = pending + np.maximum(k - 1, 0)
        peak = max(peak, int(pending.max()))
        inner = child >= 0
        frontier = child[inner]
        pending = np.repeat(pending, inner.sum(axis=1))
    return peak


def check_traversal(t: bvh.TraversalBVH, c: bvh.CanonicalBVH, tri_verts, prims) -> None:
    """Assert the traversal layout's invariants and that it matches the canonical tree."""
    n_int = t.node_bounds.shape[0]
    m = prims.shape[0]
    w = bvh.WIDTH
    assert t.node_bounds.shape == (n_int, 6 * w) and t.node_bounds.dtype == np.float32
    assert t.node_child.shape == (n_int, w) and t.node_child.dtype == np.int32
    assert t.tri_verts.shape == (m, 9) and t.tri_verts.dtype == np.float32
    assert t.tri_prim.shape == (m,) and t.tri_prim.dtype == np.int32
    n_leaves = int((c.count > 0).sum())
    assert 1 <= n_int <= max(1, c.count.shape[0] - n_leaves)
    assert np.array_equal(np.sort(t.tri_prim), np.sort(prims)), "tri_prim does not hold `prims`"
    assert np.array_equal(t.tri_verts, tri_verts[t.tri_prim]), "leaf-order copy differs"

    ref = t.node_child.astype(np.int64)
    boxes = bvh.slot_boxes(t.node_bounds)  # (node, slot, min/max, xyz)
    inner = ref >= 0
    node_of = np.broadcast_to(np.arange(n_int)[:, None], ref.shape)
    assert (ref[inner] > node_of[inner]).all() and (ref[inner] < n_int).all()
    parents = np.bincount(ref[inner], minlength=n_int)
    assert parents[0] == 0 and (parents[1:] == 1).all(), "not a tree rooted at node 0"

    # The box stored for an interior child contains all of that child's boxes.
    outer = boxes[inner]  # (K, min/max, xyz)
    kid = boxes[ref[inner]]  # (K, slot, min/max, xyz)
    assert (outer[:, None, 0] <= kid[:, :, 0]).all() and (kid[:, :, 1] <= outer[:, None, 1]).all()

    v = -1 - ref[~inner]
    first, count = v >> bvh.LEAF_COUNT_BITS, v & ((1 << bvh.LEAF_COUNT_BITS) - 1)
    leaf_box = boxes[~inner]
    empty = count == 0
    assert (leaf_box[empty, 0] > leaf_box[empty, 1]).all(), "empty slots need inverted boxes"
    assert (first[empty] == 0).all()
    # Used slots come first; every node but a leaf root (or an empty tree's) has two or more.
    used = ref != -1  # -1: an empty slot (no triangles, first 0)
    assert (np.sort(~used, axis=1) == ~used).all(), "an empty slot before a used one"
    root_is_leaf = m == 0 or c.count[0] > 0
    assert (used.sum(axis=1) >= 2).all() or (n_int == 1 and root_is_leaf)
    full = ~empty
    assert int(full.sum()) == n_leaves
    assert int(used.sum()) == n_int - 1 + n_leaves, "slots are not the tree's nodes and leaves"
    if m:
        assert count.max() <= config.BVH_MAX_LEAF
        assert covers_once(first[full], count[full], m), "leaves do not partition triangles"
        lo, hi = tri_bounds(t.tri_verts, np.arange(m), first[full], count[full])
        assert (leaf_box[full, 0] <= lo).all() and (hi <= leaf_box[full, 1]).all()
    need = traversal_stack_need(t)
    assert need == bvh.stack_need(t.node_child)
    assert need <= bvh.MAX_STACK_NEED and 2 * need + 4 <= config.TRAVERSAL_STACK_SIZE


def check_all(tri_verts: np.ndarray, prims=None) -> int:
    """Build, flatten and check both layouts; returns the depth."""
    tri_verts = np.ascontiguousarray(tri_verts, dtype=np.float32)
    c = bvh.build(tri_verts, prims)
    p = np.arange(tri_verts.shape[0], dtype=np.int32) if prims is None else np.asarray(prims)
    depth = check_canonical(c, tri_verts, p)
    check_traversal(bvh.to_traversal(c, tri_verts), c, tri_verts, p)
    return depth


@settings(max_examples=40)
@given(
    n=st.integers(1, 400),
    kind=st.sampled_from(SOUP_KINDS),
    exponent=st.integers(-30, 30),
    seed=st.integers(0, 2**32 - 1),
)
def test_random_soups(n, kind, exponent, seed):
    """Random soups of every kind, at scales from 1e-30 to 1e30, give valid BVHs."""
    tris = soup(np.random.default_rng(seed), n, kind) * np.float32(10.0**exponent)
    check_all(tris)


@settings(max_examples=20)
@given(n=st.integers(1, 300), seed=st.integers(0, 2**32 - 1), data=st.data())
def test_prims_subset(n, seed, data):
    """With ``prims`` (a subset, in any order) the leaves cover exactly that subset."""
    rng = np.random.default_rng(seed)
    tris = soup(rng, n)
    k = data.draw(st.integers(0, n), label="subset size")
    prims = rng.permutation(n)[:k].astype(np.int32)
    check_all(tris, prims)


@pytest.mark.parametrize(
    "tris",
    [icosphere(3), box(), box((1e-6, 3.0, 1e6))],
    ids=["icosphere", "cube", "flat-box"],
)
def test_meshes(tris):
    """Closed meshes (shared vertices, axis-aligned faces) give valid BVHs."""
    check_all(tris)


def test_collapse_fills_wide_nodes():
    """On a mesh the wide tree uses most of its slots (nodes over two leaves keep two) and has
    at most half as many nodes as the binary tree has interior nodes."""
    tris = icosphere(4)
    c = bvh.build(tris)
    t = bvh.to_traversal(c, tris)
    binary_interior = int((c.count == 0).sum())
    used = (t.node_child != -1).sum(axis=1)
    assert used.mean() >= 3.0, used.mean()
    assert t.node_child.shape[0] <= 0.5 * binary_interior


def test_one_triangle():
    """One triangle: a single leaf root, flattened into one node with an empty right side."""
    tris = np.array([[0, 0, 0, 1, 0, 0, 0, 1, 0]], np.float32)
    c = bvh.build(tris)
    assert c.count.tolist() == [1] and c.prim_order.tolist() == [0]
    t = bvh.to_traversal(c, tris)
    assert t.node_child.shape == (1, bvh.WIDTH)
    assert bvh.decode_leaf(t.node_child[0, 0]) == (0, 1)
    assert [bvh.decode_leaf(x) for x in t.node_child[0, 1:]] == [(0, 0)] * (bvh.WIDTH - 1)
    check_all(tris)


def test_no_triangles():
    """No triangles: an empty, inverted root that any traversal rejects."""
    tris = np.zeros((0, 9), np.float32)
    c = bvh.build(tris)
    assert c.count.shape == (1,) and c.prim_order.shape == (0,)
    t = bvh.to_traversal(c, tris)
    assert t.tri_verts.shape == (0, 9)
    assert [bvh.decode_leaf(x)[1] for x in t.node_child[0]] == [0] * bvh.WIDTH
    check_all(tris)


def test_prims_can_be_empty():
    """An empty ``prims`` over a non-empty triangle array is an empty tree."""
    tris = soup(np.random.default_rng(0), 10)
    c = bvh.build(tris, np.zeros(0, np.int32))
    assert c.count.tolist() == [0]
    check_all(tris, np.zeros(0, np.int32))


@pytest.mark.parametrize("n", [2, config.BVH_MAX_LEAF, config.BVH_MAX_LEAF + 1, 50])
def test_identical_triangles(n):
    """Copies of one triangle (no split plane exists) still end in leaves of at most
    ``BVH_MAX_LEAF`` triangles."""
    tris = np.tile(np.array([0, 0, 0, 1, 0, 0, 0, 1, 0], np.float32), (n, 1))
    check_all(tris)


def test_many_identical_centroids():
    """10^5 triangles sharing one centroid (binning cannot separate them) build a balanced
    tree: median splits, depth about log2(n / BVH_MAX_LEAF)."""
    n = 100_000
    rng = np.random.default_rng(5)
    half = rng.uniform(0.01, 1.0, size=(n, 3)).astype(np.float32)
    # Boxes symmetric about the origin: every centroid is exactly (0, 0, 0).
    tris = np.concatenate([-half, half, np.zeros_like(half)], axis=1)
    tris[:, 6] = half[:, 0]
    tris[:, 7] = -half[:, 1]
    depth = check_all(tris)
    assert depth <= math.ceil(math.log2(n)) + 1


def test_coplanar_soup():
    """10^5 triangles in one plane (zero extent on one axis) give a valid, shallow tree."""
    n = 100_000
    tris = soup(np.random.default_rng(6), n, "planar")
    depth = check_all(tris)
    assert depth <= 3 * math.ceil(math.log2(n))


def test_exponentially_spaced():
    """Centroids at 2^-100 ... 2^100 (SAH peels one off per level) reach the build-depth cap
    and still give a valid tree within the documented depth bound."""
    x = 2.0 ** np.arange(-100, 101, 2)
    a = x / 64.0
    tris = np.stack([x, -a, -a, x, a, -a, x, np.zeros_like(a), a], axis=1).astype(np.float32)
    depth = check_all(tris)
    assert depth >= config.BVH_MAX_BUILD_DEPTH // 2, "the adversarial input lost its bite"


@settings(max_examples=10)
@given(n=st.integers(0, 500), kind=st.sampled_from(SOUP_KINDS), seed=st.integers(0, 2**32 - 1))
def test_build_is_deterministic(n, kind, seed):
    """Building twice from equal input gives bit-identical arrays in both layouts."""
    tris = soup(np.random.default_rng(seed), n, kind)
    a = bvh.build(tris)
    b = bvh.build(tris.copy())
    for x, y in zip(a, b, strict=True):
        assert x.dtype == y.dtype and np.array_equal(x, y)
    ta = bvh.to_traversal(a, tris)
    tb = bvh.to_traversal(b, tris.copy())
    for x, y in zip(ta, tb, strict=True):
        assert x.dtype == y.dtype and np.array_equal(x, y)


def test_rejects_bad_shapes():
    """Triangle arrays not of shape (T, 9) are refused."""
    with pytest.raises(ValueError, match=r"\(T, 9\)"):
        bvh.build(np.zeros((4, 3), np.float32))


def test_decode_leaf_round_trip():
    """``decode_leaf`` inverts the leaf encoding of the module docstring."""
    for first, count in [(0, 0), (0, 1), (5, 4), (bvh.MAX_TRIANGLES - 4, 4)]:
        ref = -1 - ((first << bvh.LEAF_COUNT_BITS) | count)
        assert ref < 0
        assert bvh.decode_leaf(ref) == (first, count)


def deep_stack_triangles(core: int) -> np.ndarray:
    """A crafted soup whose tree needs more than ``TRAVERSAL_STACK_SIZE`` stack entries: 48
    pairs of triangles on the +x axis 32x apart (SAH peels one pair a level, and each pair is
    split again, so every level of the chain has two interior children), then ``core`` copies of
    one triangle at the origin, split at the index median below the depth cap."""

    def tri(x, a):
        return np.stack([x, -a, -a, x, a, -a, x, np.zeros_like(a), a], axis=1)

    x = 2.0 ** (-115.0 + 5.0 * np.arange(48))
    pairs = np.concatenate([tri(x, x / 64), tri(1.125 * x, x / 64)])
    cores = tri(np.zeros(core), np.ones(core))
    return np.concatenate([cores, pairs]).astype(np.float32)


@pytest.mark.slow
def test_traversal_stack_bound_holds_for_crafted_input():
    """The traversal stack suffices for a crafted input that needs many entries (its tree may
    be kept two-wide for that)."""
    tris = deep_stack_triangles(2_100_000)
    c = bvh.build(tris)
    assert traversal_stack_need(bvh.to_traversal(c, tris)) <= bvh.MAX_STACK_NEED


@pytest.mark.slow
def test_traversal_stays_in_its_stack(tmp_path):
    """A ray through the crafted tree stays inside the traversal stack (checked by numba's
    bounds checking, in a subprocess with its own kernel cache)."""
    script = textwrap.dedent(
        """
        import numpy as np
        from tests.tracer.test_bvh import deep_stack_triangles
        from tests.helpers import traversal
        from tracer.geometry.raycast import closest_hits

        tris = deep_stack_triangles(2_100_000)
        hits = closest_hits(traversal(tris), [[-1.0, 0, 0]], [[1.0, 0, 0]], threads=1)
        assert hits.t[0] == 1.0
        """
    )
    env = dict(os.environ, NUMBA_BOUNDSCHECK="1", TILERENDER_NUMBA_CACHE=str(tmp_path))
    env.pop("NUMBA_CACHE_DIR", None)
    result = subprocess.run(
        [sys.executable, "-c", script], cwd=ROOT, env=env, capture_output=True, text=True
    )
    if result.returncode != 0 and "IndexError" not in result.stderr:
        pytest.fail(f"the script failed for another reason: {result.stderr[-2000:]}")
    assert result.returncode == 0, result.stderr.strip().splitlines()[-1]


def _corrupt_leaf_box(c, t):
    leaf = int(np.flatnonzero(c.count > 0)[0])
    c.node_max[leaf] = np.nextafter(c.node_max[leaf], np.float32(-np.inf))


def _corrupt_interior_box(c, t):
    c.node_min[0] = np.nextafter(c.node_min[0], np.float32(np.inf))


def _corrupt_prim_order(c, t):
    c.prim_order[1] = c.prim_order[0]


def _corrupt_child(c, t):
    c.left_first[0] = c.left_first[0] + 2


def _corrupt_traversal_box(t_):
    t_.node_bounds[0, 12] = t_.node_bounds[0, 0] - 1  # slot 0: max x below min x


def _corrupt_traversal_leaf(t_):
    leaf = np.argwhere(t_.node_child < 0)[0]
    first, count = bvh.decode_leaf(t_.node_child[tuple(leaf)])
    t_.node_child[tuple(leaf)] = -1 - ((first << bvh.LEAF_COUNT_BITS) | (count - 1))


def _corrupt_traversal_verts(t_):
    t_.tri_verts[[0, 1]] = t_.tri_verts[[1, 0]]


@pytest.mark.parametrize(
    "corrupt",
    [
        _corrupt_leaf_box,
        _corrupt_interior_box,
        _corrupt_prim_order,
        _corrupt_child,
        _corrupt_traversal_box,
        _corrupt_traversal_leaf,
        _corrupt_traversal_verts,
    ],
)
def test_checks_catch_corruption(corrupt):
    """The structural checks above have teeth: each one-element corruption is caught."""
    tris = soup(np.random.default_rng(9), 64)
    c = bvh.CanonicalBVH(*(a.copy() for a in bvh.build(tris)))
    t = bvh.to_traversal(c, tris)
    prims = np.arange(64, dtype=np.int32)
    if corrupt.__code__.co_argcount == 2:
        corrupt(c, t)
    else:
        t = bvh.TraversalBVH(*(a.copy() for a in t))
        corrupt(t)
    with pytest.raises(AssertionError):
        check_canonical(c, tris, prims)
        check_traversal(t, c, tris, prims)

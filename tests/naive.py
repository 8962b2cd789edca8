"""Slow, obvious oracles for ray queries: every ray against every triangle, in float64 numpy.

The intersection test is Moller-Trumbore in float64 on the float32 vertices. It is not the
tracer's watertight test, so the two may disagree where a ray grazes an edge, a vertex, the
ray's own origin, ``t_max`` or a plane it is parallel to. The oracle therefore classifies each
(ray, triangle) pair with a safety margin:

* a *certain* hit: barycentrics all above ``MARGIN``, ``t`` clearly inside (0, t_max), and the
  ray clearly not parallel to the plane;
* a *possible* hit: the same conditions with the margin turned the other way (or a ray nearly
  parallel to the plane, where Moller-Trumbore says little);
* otherwise a certain miss.

A ray is *ambiguous* when a possible-but-not-certain hit could be the closest; for every other
ray the answer is exact. The tests check that ambiguous rays are rare, so the oracle keeps its
teeth.
"""

from dataclasses import dataclass

import numpy as np

MARGIN = 1e-9
"""Relative margin on barycentrics, on ``t`` and on the parallel test."""
T_RTOL = 1e-9
"""Relative tolerance on ``t``: hits this close are ties, and the tracer's ``t`` must agree."""
CHUNK_PAIRS = 1 << 20
"""Ray-triangle pairs evaluated at once (bounds the oracle's memory)."""


@dataclass
class NaiveHits:
    """The oracle's answer for N rays over T triangles."""

    t: np.ndarray
    """(N,) float64: closest certain hit (inf when there is none)."""
    acceptable: np.ndarray
    """(N, T) bool: triangles the tracer may report (certain ties at ``t`` for a clear ray;
    also possible hits no farther than ``t`` for an ambiguous one)."""
    ambiguous: np.ndarray
    """(N,) bool: a possible-but-uncertain hit might be the closest."""
    any_certain: np.ndarray
    """(N,) bool: some certain hit in (0, t_max)."""
    any_possible: np.ndarray
    """(N,) bool: some possible hit in (0, t_max)."""


def _pairs(tri_verts, origins, directions, t_max):
    """Certain and possible hit masks and ``t`` for every (ray, triangle) pair, shape (n, T)."""
    v = tri_verts.astype(np.float64).reshape(-1, 3, 3)
    v0, v1, v2 = v[:, 0], v[:, 1], v[:, 2]
    e1 = v1 - v0
    e2 = v2 - v0
    o = origins[:, None, :]
    d = directions[:, None, :]
    p = np.cross(d, e2[None])
    det = np.einsum("ntk,ntk->nt", np.broadcast_to(e1[None], p.shape), p)
    d_len = np.linalg.norm(directions, axis=1)[:, None]
    scale = d_len * np.linalg.norm(e1, axis=1)[None] * np.linalg.norm(e2, axis=1)[None]
    parallel = np.abs(det) <= MARGIN * scale
    normal = np.cross(e1, e2)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        inv = 1.0 / det
        s = o - v0[None]
        u = np.einsum("ntk,ntk->nt", s, p) * inv
        q = np.cross(s, np.broadcast_to(e1[None], s.shape))
        w = np.einsum("ntk,ntk->nt", np.broadcast_to(d, q.shape), q) * inv
        t = np.einsum("ntk,ntk->nt", np.broadcast_to(e2[None], q.shape), q) * inv
        b_min = np.minimum(np.minimum(1.0 - u - w, u), w)
        # Length scale of the pair: how far from the origin ``t`` must be to count as positive.
        length = np.abs(s).max(axis=2) + np.abs(e1).max(axis=1)[None] + np.abs(e2).max(axis=1)[None]
        t_len = t * d_len
        tm = t_max[:, None]
        in_range = (t_len >= -MARGIN * length) & (t <= tm * (1.0 + MARGIN))
        certain = (
            ~parallel & (b_min > MARGIN) & (t_len > MARGIN * length) & (t < tm * (1.0 - MARGIN))
        )
        # Nearly parallel: barycentrics lose accuracy, so accept anything roughly inside, and
        # any ray that runs (nearly) in the triangle's plane.
        plane_dist = np.abs(np.einsum("ntk,tk->nt", s, normal)) / np.linalg.norm(normal, axis=1)
        parallel_possible = parallel & (
            (plane_dist <= MARGIN * length) | ((b_min >= -1e-3) & in_range)
        )
        possible = parallel_possible | (~parallel & (b_min >= -MARGIN) & in_range)
    t = np.where(np.isfinite(t), t, np.inf)
    return certain, possible & ~certain, parallel, t


def closest_hits(
    tri_verts: np.ndarray,
    origins: np.ndarray,
    directions: np.ndarray,
    t_max: np.ndarray | float | None = None,
) -> NaiveHits:
    """Brute-force closest hits of rays ``o + t d``, ``t`` in (0, t_max), over every triangle."""
    tri_verts = np.asarray(tri_verts, dtype=np.float32)
    origins = np.asarray(origins, dtype=np.float64).reshape(-1, 3)
    directions = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    n, n_tri = origins.shape[0], tri_verts.shape[0]
    t_max = np.broadcast_to(np.inf if t_max is None else t_max, (n,)).astype(np.float64)
    out = NaiveHits(
        t=np.full(n, np.inf),
        acceptable=np.zeros((n, n_tri), bool),
        ambiguous=np.zeros(n, bool),
        any_certain=np.zeros(n, bool),
        any_possible=np.zeros(n, bool),
    )
    step = max(1, CHUNK_PAIRS // max(1, n_tri))
    for a in range(0, n, step):
        b = min(n, a + step)
        certain, maybe, parallel, t = _pairs(tri_verts, origins[a:b], directions[a:b], t_max[a:b])
        t_c = np.where(certain, t, np.inf).min(axis=1, initial=np.inf)
        near = t <= t_c[:, None] * (1.0 + T_RTOL)
        ties = certain & near & (t >= t_c[:, None] * (1.0 - T_RTOL))
        doubt = maybe & (near | parallel | ~np.isfinite(t_c)[:, None])
        out.t[a:b] = t_c
        out.ambiguous[a:b] = doubt.any(axis=1)
        out.acceptable[a:b] = ties | doubt
        out.any_certain[a:b] = certain.any(axis=1)
        out.any_possible[a:b] = (certain | maybe).any(axis=1)
    return out


def any_hits(tri_verts, origins, directions, t_max=None) -> tuple[np.ndarray, np.ndarray]:
    """Brute-force occlusion: ``(answer, ambiguous)``, both bool (N,). Where ``ambiguous``,
    either answer is right."""
    result = closest_hits(tri_verts, origins, directions, t_max)
    ambiguous = result.any_possible & ~result.any_certain
    return result.any_certain, ambiguous


def assert_closest_match(
    hits, expected: NaiveHits, max_ambiguous: float = 0.01, t_rtol: float = T_RTOL
) -> None:
    """Assert the tracer's ``hits`` agree with the oracle: for a clear ray, the same closest
    ``t`` (relative ``T_RTOL``) and one of the triangles hit there; for an ambiguous ray, an
    acceptable triangle no farther than the closest certain hit, or a miss only when there is
    no certain hit. ``t_rtol`` may be loosened for ill-conditioned (grazing) rays."""
    n = expected.t.shape[0]
    assert hits.prim.shape == (n,)
    assert not np.isnan(hits.t).any(), "the tracer returned a NaN distance"
    clear = ~expected.ambiguous
    assert expected.ambiguous.mean() <= max_ambiguous, (
        f"{expected.ambiguous.sum()} of {n} rays are ambiguous: the test lost its power"
    )
    rows = np.arange(n)
    prim = hits.prim.astype(np.int64)
    valid = prim >= 0
    picked = np.zeros(n, bool)
    picked[valid] = expected.acceptable[rows[valid], prim[valid]]

    miss_expected = clear & ~np.isfinite(expected.t)
    bad = np.flatnonzero(miss_expected & valid)
    assert bad.size == 0, f"{bad.size} rays hit where the oracle finds nothing, e.g. ray {bad[:5]}"
    bad = np.flatnonzero(clear & np.isfinite(expected.t) & ~picked)
    assert bad.size == 0, (
        f"{bad.size} rays report the wrong triangle, e.g. ray {bad[0]}: "
        f"got {prim[bad[0]]} at t={hits.t[bad[0]]!r}, expected t={expected.t[bad[0]]!r}"
    )
    hit = clear & np.isfinite(expected.t)
    err = np.abs(hits.t[hit] - expected.t[hit]) / expected.t[hit]
    assert (err <= t_rtol).all(), f"t differs by up to {err.max():.3g} relative"
    assert np.isinf(hits.t[~valid]).all(), "a miss must report t = inf"

    amb = expected.ambiguous
    bad = np.flatnonzero(amb & valid & ~picked)
    assert bad.size == 0, f"ambiguous rays report an impossible triangle, e.g. ray {bad[:5]}"
    bad = np.flatnonzero(amb & ~valid & np.isfinite(expected.t))
    assert bad.size == 0, f"ambiguous rays miss a certain hit, e.g. ray {bad[:5]}"
    amb_hit = amb & valid
    assert (hits.t[amb_hit] > 0.0).all(), "a hit must have t > 0"
    late = amb_hit & (hits.t > expected.t * (1.0 + T_RTOL))
    assert not late.any(), f"ambiguous rays report a hit beyond the closest certain one: {late}"

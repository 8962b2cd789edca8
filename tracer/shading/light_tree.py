"""The light tree: choosing one emissive triangle by its importance as seen from a point.

A binary BVH over the emissive triangles (built by ``tracer.compiled.light_tree``), each node
bounding its triangles' positions, the cone of their normals and their summed power. From a
shading point ``p`` with normal ``n`` a walk from the root picks a child by the children's
importance (pbrt-v4's ``LightBounds::Importance``: power over squared distance, times the best
cosines the bounds allow at the emitters and at ``p``) until it reaches a triangle; the
triangle's probability is the product of the choices. ``tree_pmf`` recomputes that product for
a given triangle from its bit trail (a set bit: the second child), in the same order and with
the same expressions, so sampling and MIS see the same bits. ``docs/effects.md`` ("Many
lights").

Emitters are area lights: they emit over the hemisphere of their normal (two-sided ones over
both), so a node's emission cone is its normal cone widened by 90 degrees. The importance at
``p`` counts only light arriving above ``n``: the BSDFs that sample lights reflect only.
"""

import numpy as np

from tracer.kernel.jit import jit, jit_inline

NODE = 11
"""Columns of ``light_tree_nodes``: ``CENTRE`` (3) and ``RADIUS2`` the sphere around the box
of the triangles (its centre and squared radius), ``AXIS`` (3) the unit axis of their normals'
cone, ``COS_O`` and ``SIN_O`` its half-angle, ``PHI`` their summed selection weight,
``TWO_SIDED`` 1 if any of them emits on both sides."""
CENTRE = 0
RADIUS2 = 3
AXIS = 4
COS_O = 7
SIN_O = 8
PHI = 9
TWO_SIDED = 10

ONE_MINUS_EPSILON = 0.99999999999999989
"""The largest float64 below 1: a rescaled random number stays in [0, 1)."""
NOT_TREE = -2
"""``tree_pick``'s entry when the random number falls on the lights beside the tree."""


@jit_inline
def _safe_sqrt(x):
    return np.sqrt(max(0.0, x))


@jit_inline
def _cos_sub_lazy(cos_a, cos_b, sin_b):
    """cos(max(0, a - b)) for angles a, b in [0, pi], taking sin(a) only when needed."""
    if cos_a > cos_b:
        return 1.0
    return cos_a * cos_b + _safe_sqrt(1.0 - cos_a * cos_a) * sin_b


@jit_inline
def importance(nodes, i, p, n):
    """How much node ``i``'s triangles may light the point ``p`` with normal ``n`` (a bound
    on power / distance^2 times the emitter and receiver cosines; 0 only where none can)."""
    dx = p[0] - nodes[i, CENTRE]
    dy = p[1] - nodes[i, CENTRE + 1]
    dz = p[2] - nodes[i, CENTRE + 2]
    d2 = dx * dx + dy * dy + dz * dz
    r2 = nodes[i, RADIUS2]
    if d2 <= r2:  # inside the bounding sphere: every direction and cosine is possible
        return nodes[i, PHI] / max(r2, 1e-300)
    inv = 1.0 / np.sqrt(d2)
    wx = dx * inv  # from the centre toward p
    wy = dy * inv
    wz = dz * inv
    sin2_b = r2 / d2
    cos_b = np.sqrt(1.0 - sin2_b)  # half-angle of the sphere seen from p
    sin_b = np.sqrt(sin2_b)
    # Emitter side: the angle from the cone to p, less the cone's and the sphere's half-angles.
    cos_w = nodes[i, AXIS] * wx + nodes[i, AXIS + 1] * wy + nodes[i, AXIS + 2] * wz
    if nodes[i, TWO_SIDED] != 0.0:
        cos_w = abs(cos_w)
    cos_o = nodes[i, COS_O]
    if cos_w <= cos_o:  # p outside the normal cone
        sin_w = _safe_sqrt(1.0 - cos_w * cos_w)
        sin_o = nodes[i, SIN_O]
        cos_x = cos_w * cos_o + sin_w * sin_o
        sin_x = sin_w * cos_o - cos_w * sin_o
        if cos_x <= cos_b and cos_x * cos_b + sin_x * sin_b <= 0.0:
            return 0.0  # p is behind every emitter
        cos_e = 1.0 if cos_x > cos_b else cos_x * cos_b + sin_x * sin_b
    else:
        cos_e = 1.0
    # Receiver side: the angle from n to the sphere, less the sphere's half-angle.
    cos_r = _cos_sub_lazy(-(n[0] * wx + n[1] * wy + n[2] * wz), cos_b, sin_b)
    if cos_r <= 0.0:  # every emitter is below p's surface
        return 0.0
    return nodes[i, PHI] * cos_e * cos_r / d2


@jit
def tree_sample(nodes, child, p, n, u):
    """A triangle for the point ``p`` with normal ``n``, chosen by ``u`` in [0, 1):
    ``(light, pmf)``, its index among the emissive triangles (the first entries of the light
    table) and probability; ``(-1, 0.0)`` when no triangle can light ``p``."""
    i = 0
    pmf = 1.0
    if child[0] < 0:
        if importance(nodes, 0, p, n) > 0.0:
            return -1 - child[0], 1.0
        return -1, 0.0
    while child[i] >= 0:
        c0 = importance(nodes, i + 1, p, n)
        c1 = importance(nodes, child[i], p, n)
        total = c0 + c1
        if not total > 0.0:
            return -1, 0.0
        p0 = c0 / total
        if u < p0:
            u = min(u / p0, ONE_MINUS_EPSILON)
            pmf *= p0
            i = i + 1
        else:
            u = min((u - p0) / (1.0 - p0), ONE_MINUS_EPSILON)
            pmf *= c1 / total
            i = child[i]
    return -1 - child[i], pmf


@jit
def tree_pmf(nodes, child, bits, light, p, n):
    """The probability with which ``tree_sample`` picks triangle ``light`` for ``p`` and
    ``n`` (the same products in the same order)."""
    if child[0] < 0:
        return 1.0 if importance(nodes, 0, p, n) > 0.0 else 0.0
    trail = bits[light]
    i = 0
    pmf = 1.0
    while child[i] >= 0:
        c0 = importance(nodes, i + 1, p, n)
        c1 = importance(nodes, child[i], p, n)
        total = c0 + c1
        if not total > 0.0:
            return 0.0
        if trail & np.uint64(1):
            pmf *= c1 / total
            i = child[i]
        else:
            pmf *= c0 / total
            i = i + 1
        trail = trail >> np.uint64(1)
    return pmf


@jit
def tree_light_of(keys, key_light, k, j):
    """The index among the emissive triangles of row ``j`` of instance ``k``'s pool, or -1."""
    key = (np.int64(k) << np.int64(32)) | np.int64(j)
    at = np.searchsorted(keys, key)
    if at < keys.shape[0] and keys[at] == key:
        return key_light[at]
    return -1


@jit_inline
def _share(cdf, area):
    """The probability that light selection picks the tree (its emissive triangles are the
    first entries of the power CDF): their share of the power."""
    return cdf[area.shape[0] - 1]


@jit
def tree_pick(cdf, nodes, child, area, u0, p, n):
    """Light selection by ``u0`` with the tree: ``(entry, density)``, a triangle picked by the
    tree from its share of ``u0`` (rescaled) and its area density (share times PMF over area),
    or ``(NOT_TREE, -1.0)`` when ``u0`` falls on the other lights (pick them by power), or
    ``(-1, 0.0)`` when the tree has no triangle for ``p``."""
    share = _share(cdf, area)
    if not u0 < share:
        return NOT_TREE, -1.0
    e, pmf = tree_sample(nodes, child, p, n, min(u0 / share, ONE_MINUS_EPSILON))
    if e < 0:
        return -1, 0.0
    return e, share * pmf / area[e]


@jit
def tree_hit_density(cdf, nodes, child, bits, area, keys, key_light, k, j, p, n):
    """The area density with which ``tree_pick`` at ``p`` (normal ``n``) picks the point of
    row ``j`` of instance ``k``'s pool that a ray hit (0 if it is not an emissive triangle)."""
    e = tree_light_of(keys, key_light, k, j)
    if e < 0:
        return 0.0
    return _share(cdf, area) * tree_pmf(nodes, child, bits, e, p, n) / area[e]

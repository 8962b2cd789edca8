"""The environment map as a light: importance-sampling tables over its pixels, and the kernels'
radiance lookup, sampling and density.

Mapping (``docs/scene-format.md``): pixel ``(row i, column j)`` of an H x W image covers
``v = (i + [0, 1)) / H`` and ``u = (j + [0, 1)) / W``; the polar angle from +y is
``theta = pi v`` and the azimuth ``phi = 2 pi (u - 1/2)``, so the direction in the map's frame is
``(sin theta sin phi, cos theta, -sin theta cos phi)``: the image centre looks along -z and ``u``
grows toward +x. The map is then turned by ``rotation`` about +y. Radiance is constant over a
pixel (nearest-pixel lookup), like the sampling density.

Sampling (pbrt's ``PiecewiseConstant2D``): pixel weights ``luminance * sin(theta)`` (theta at the
row's centre) give a marginal distribution over rows and one conditional distribution over
columns per row, stored as CDFs and inverted by binary search; within the chosen pixel ``(u, v)``
is uniform. The density over ``(u, v)`` is ``p(u, v) = H W P(pixel)``, and in solid angle
``p(u, v) / (2 pi^2 sin theta)`` (``dw = 2 pi^2 sin theta du dv``). Both read the same CDF
differences, so the density used when a direction is sampled and the one looked up when a ray
escapes along it are the same number.
"""

import math
from typing import NamedTuple

import numpy as np

from tracer.kernel.jit import jit
from tracer.maths import portable

LUMINANCE = np.array([0.2126, 0.7152, 0.0722])
"""Rec. 709 luminance weights: every channel counts, so a pixel with any radiance can be
sampled."""
INV_2PI2 = 1.0 / (2.0 * math.pi * math.pi)


class EnvironmentTables(NamedTuple):
    """What the kernels read of an environment map."""

    image: np.ndarray
    """float32 (H, W, 3): radiance with the map's scale applied."""
    rows: np.ndarray
    """float64 (H + 1,): CDF of the marginal distribution over rows (0 first, exactly 1 last)."""
    cols: np.ndarray
    """float64 (H, W + 1): CDF of each row's conditional distribution over its columns."""


def _cdf(weights: np.ndarray) -> np.ndarray:
    """CDFs (with a leading 0) of the last axis of ``weights``; an all-zero row is uniform."""
    cdf = np.zeros(weights.shape[:-1] + (weights.shape[-1] + 1,))
    np.cumsum(weights, axis=-1, out=cdf[..., 1:])
    total = cdf[..., -1:].copy()
    empty = total[..., 0] <= 0.0
    cdf[~empty] /= total[~empty]  # the last entry becomes x / x = 1 exactly
    cdf[empty] = np.linspace(0.0, 1.0, weights.shape[-1] + 1)
    return cdf


def sampling_tables(image: np.ndarray, scale: float = 1.0, by_luminance: bool = True):
    """The ``EnvironmentTables`` of ``image`` (float32 (H, W, 3)) times ``scale``.

    ``by_luminance`` False weights every pixel by ``sin(theta)`` alone: close to uniform
    sampling of the sphere, for measuring what importance sampling gains.
    """
    scaled = (image.astype(np.float64) * scale).astype(np.float32)
    h, w = scaled.shape[:2]
    sin_theta = portable.elementwise(math.sin, np.pi * (np.arange(h) + 0.5) / h)
    if by_luminance:
        rgb = scaled.astype(np.float64)
        luminance = rgb[..., 0] * LUMINANCE[0] + rgb[..., 1] * LUMINANCE[1]
        weights = (luminance + rgb[..., 2] * LUMINANCE[2]) * sin_theta[:, None]
    else:
        weights = np.broadcast_to(sin_theta[:, None], (h, w))
    cols = _cdf(weights)
    rows = _cdf(weights.sum(axis=1))
    return EnvironmentTables(scaled, rows, cols)


def empty_tables() -> EnvironmentTables:
    """Tables of no map (for scenes without one: the kernels never read them)."""
    return EnvironmentTables(np.zeros((1, 1, 3), np.float32), np.array([0.0, 1.0]),
                             np.array([[0.0, 1.0]]))  # fmt: skip


@jit
def find_interval(cdf, u):
    """The ``i`` with ``cdf[i] <= u < cdf[i + 1]`` for ``0 <= u < cdf[-1]``: never an interval
    of zero width."""
    lo = 0
    hi = cdf.shape[0] - 1
    while hi - lo > 1:
        mid = (lo + hi) >> 1
        if cdf[mid] <= u:
            lo = mid
        else:
            hi = mid
    return lo


@jit
def environment_sample(image, rows, cols, cos_r, sin_r, u1, u2):
    """A direction toward the map drawn by ``(u1, u2)``: ``(wi, L, pdf)``, the unit world
    direction, the radiance arriving from it and its solid-angle density (0 on failure)."""
    h = image.shape[0]
    w = image.shape[1]
    i = find_interval(rows, u1)
    p_row = rows[i + 1] - rows[i]
    v = (i + min(1.0, (u1 - rows[i]) / p_row)) / h
    row = cols[i]
    j = find_interval(row, u2)
    p_col = row[j + 1] - row[j]
    u = (j + min(1.0, (u2 - row[j]) / p_col)) / w
    theta = math.pi * v
    sin_t = math.sin(theta)
    if not sin_t > 0.0:
        return (0.0, 1.0, 0.0), (0.0, 0.0, 0.0), 0.0
    phi = 2.0 * math.pi * (u - 0.5)
    mx = sin_t * math.sin(phi)
    mz = -sin_t * math.cos(phi)
    wi = (cos_r * mx + sin_r * mz, math.cos(theta), cos_r * mz - sin_r * mx)
    pdf = (p_row * h) * (p_col * w) * INV_2PI2 / sin_t
    L = (np.float64(image[i, j, 0]), np.float64(image[i, j, 1]), np.float64(image[i, j, 2]))
    return wi, L, pdf


@jit
def environment_lookup(image, rows, cols, cos_r, sin_r, d):
    """``(L, pdf)``: the radiance arriving along ``-d`` (seen looking along the unit world
    direction ``d``) and the solid-angle density with which :func:`environment_sample` picks
    ``d``."""
    h = image.shape[0]
    w = image.shape[1]
    mx = cos_r * d[0] - sin_r * d[2]
    mz = sin_r * d[0] + cos_r * d[2]
    sin_t = math.sqrt(mx * mx + mz * mz)
    v = math.atan2(sin_t, d[1]) / math.pi
    u = math.atan2(mx, -mz) / (2.0 * math.pi) + 0.5
    i = min(max(int(v * h), 0), h - 1)
    j = min(max(int(u * w), 0), w - 1)
    L = (np.float64(image[i, j, 0]), np.float64(image[i, j, 1]), np.float64(image[i, j, 2]))
    if not sin_t > 0.0:
        return L, 0.0
    p = (rows[i + 1] - rows[i]) * h * (cols[i, j + 1] - cols[i, j]) * w
    return L, p * INV_2PI2 / sin_t

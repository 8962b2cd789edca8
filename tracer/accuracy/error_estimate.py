"""Image error against a reference, and the error of a render estimated without one.

Images are float (H, W, 3) linear radiance. Definitions (``docs/accuracy.md``):

- **relative MSE**: the mean over pixels and channels of ``(x - ref)^2 / (ref^2 + eps)``, with
  ``eps = REL_EPSILON``; the **relative error** is its square root (relative RMS error);
- **RMSE**: the root mean square difference in linear radiance;
- **PSNR**: ``10 log10(1 / MSE)`` of the display images (clamped to [0, 1], sRGB-encoded);
- the **noise floor** of a reference with per-pixel variance ``var``: the relative MSE that
  the reference's own noise adds, on average, to any image compared with it.

The online estimate (:func:`estimate_rel_mse`) needs no reference: a render split into
``PARTS`` independent parts of equal sample counts (disjoint sample ranges) estimates the
variance of their mean from their spread, the expected squared error of an unbiased render;
the function's docstring explains its denominator and when it returns None. Where the parts
cannot tell a pixel's value (a light smaller than a pixel, seen by one or two parts), a few
*spot checks* (:class:`SpotChecks`: those pixels rendered again with many more samples,
independently, by ``tracer.accuracy.spot_check``) measure its error directly.
"""

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

Images = np.ndarray | Sequence[np.ndarray]
"""Parts of a render: a (K, H, W, 3) array or K (H, W, 3) images."""

REL_EPSILON = 1e-2
"""``eps`` of the relative MSE: keeps black pixels from dividing by zero, and makes errors in
pixels darker than about ``sqrt(eps) = 0.1`` count as absolute rather than relative ones."""


def _pair(x: np.ndarray, ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    x = np.asarray(x, dtype=np.float64)
    ref = np.asarray(ref, dtype=np.float64)
    if x.shape != ref.shape or x.ndim != 3 or x.shape[2] != 3:
        raise ValueError(
            f"expected two (H, W, 3) images of one shape, got {x.shape} and {ref.shape}"
        )
    return x, ref


def rel_mse_terms(x: np.ndarray, ref: np.ndarray, eps: float = REL_EPSILON) -> np.ndarray:
    """Per pixel and channel ``(x - ref)^2 / (ref^2 + eps)``, float64 (H, W, 3)."""
    x, ref = _pair(x, ref)
    return (x - ref) ** 2 / (ref * ref + eps)


def rel_mse(x: np.ndarray, ref: np.ndarray, eps: float = REL_EPSILON) -> float:
    """Relative MSE of ``x`` against ``ref`` (mean of :func:`rel_mse_terms`)."""
    return float(np.mean(rel_mse_terms(x, ref, eps)))


def noise_floor(ref: np.ndarray, var_of_mean: np.ndarray, eps: float = REL_EPSILON) -> float:
    """The relative MSE a reference's own noise adds: mean of ``var / (ref^2 + eps)``.

    For an image ``x`` independent of the reference ``r`` (mean ``mu``, variance ``var``),
    ``E[(x - r)^2] = E[(x - mu)^2] + var``: subtracting this floor from the measured relative
    MSE removes the reference's noise from it, on average.
    """
    ref, var = _pair(ref, var_of_mean)
    return float(np.mean(var / (ref * ref + eps)))


def rmse(x: np.ndarray, ref: np.ndarray) -> float:
    """Root mean square difference in linear radiance."""
    x, ref = _pair(x, ref)
    return float(np.sqrt(np.mean((x - ref) ** 2)))


def to_display(rgb: np.ndarray) -> np.ndarray:
    """Linear radiance clamped to [0, 1] and sRGB-encoded, float64 in [0, 1] (what a PNG shows,
    before rounding to 8 bits)."""
    x = np.clip(np.nan_to_num(np.asarray(rgb, dtype=np.float64), nan=0.0), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)


def psnr(x: np.ndarray, ref: np.ndarray) -> float:
    """PSNR in dB of the display images (peak 1); ``inf`` when they are equal."""
    x, ref = _pair(x, ref)
    mse = float(np.mean((to_display(x) - to_display(ref)) ** 2))
    return float("inf") if mse == 0.0 else float(10.0 * np.log10(1.0 / mse))


PARTS = 4
"""Independent parts a render is split into for :func:`estimate_rel_mse` (equal sample counts
over disjoint sample ranges): enough for a median that one outlier does not move."""
OUTLIER = 3.0
"""A pixel whose mean is above this factor times its denominator (one part above 9 times the
other three) has an outlier that few parts saw (see :func:`estimate_rel_mse`)."""
CORROBORATION = 0.5
"""An outlier pixel whose mean a neighbour's mean reaches to this fraction is read as a light
seen directly (see :func:`estimate_rel_mse`)."""
UNRESOLVED_PIXELS = 2
"""The pixels whose reading matters most that must not decide the estimate alone: a light
smaller than a pixel, seen by one part, shows in one or two (see :func:`estimate_rel_mse`)."""
AMBIGUITY = 1.5
"""Largest ratio of relative errors between the two readings of those pixels at which the
estimate is still given."""
SPOT_CHECKS = 16
"""Most pixels of a render that are spot-checked (``tracer.accuracy.spot_check``)."""
SPOT_CHECK_FACTOR = 64
"""Samples per pixel of a spot check, as a multiple of the render's."""
SPOT_CHECK_SHARE = 1 / 8
"""Largest share of a render's samples its spot checks may take: fewer pixels are checked in
small images (none below ``SPOT_CHECK_FACTOR / SPOT_CHECK_SHARE`` = 512 pixels)."""
CHECK_GAP = 0.01
"""Least gap between a pixel's readings, as a share of the sum of the image's error terms,
that makes it worth a spot check (:func:`pixels_to_check`)."""


@dataclass(frozen=True)
class SpotChecks:
    """A few pixels of a render rendered again, independently of it, with many more samples.

    ``pixels`` is (P, 2) int (y, x); ``parts`` is (K, P, 3) float, K >= 2 independent means
    of equal sample counts (their spread gives the checks' own variance).
    """

    pixels: np.ndarray
    parts: np.ndarray

    def __post_init__(self) -> None:
        pixels, parts = np.asarray(self.pixels), np.asarray(self.parts)
        if pixels.ndim != 2 or pixels.shape[1] != 2:
            raise ValueError(f"spot-check pixels must be (P, 2), got shape {pixels.shape}")
        if parts.ndim != 3 or parts.shape[0] < 2 or parts.shape[1:] != (len(pixels), 3):
            raise ValueError(
                f"spot-check parts must be (K >= 2, {len(pixels)}, 3), got shape {parts.shape}"
            )


def pixels_to_check(parts: Images, count: int, eps: float = REL_EPSILON) -> np.ndarray:
    """(P, 2) int (y, x), P <= ``count``: the pixels whose error the parts tell least, most
    uncertain first.

    A pixel's error term can lie anywhere between its reading as a light (the parts' mean is
    its value) and its reading with the lowest value the parts make plausible (the second
    smallest part, or the median's 3x3 floor if lower: one or two parts that saw a rare
    bright path). The pixels with the widest gap between the two are the ones to check, if
    the gap is at least ``CHECK_GAP`` of the sum of the image's terms (ordinary noise leaves
    small gaps everywhere, which no check would change much).
    """
    stack = _parts(parts)
    _, variance, floor, terms, as_light, _ = _readings(stack, eps)
    low = np.minimum(np.sort(stack, axis=0)[1], floor)
    gap = (variance / (low * low + eps) - as_light).sum(axis=2)
    order = np.argsort(gap, axis=None, kind="stable")[::-1][: max(0, count)]
    ranked = gap.flat[order]
    order = order[(ranked > 0.0) & (ranked >= CHECK_GAP * terms.sum())]
    return np.stack(np.unravel_index(order, gap.shape), axis=1).astype(np.int64)


def _readings(stack: np.ndarray, eps: float):
    """Per pixel and channel: the parts' mean, the variance of that mean, the denominator
    floor, the chosen error term, the term read as a light (see :func:`estimate_rel_mse`) and
    the chosen denominator (``mu^2 + eps`` estimated)."""
    mean = stack.mean(axis=0)
    variance = stack.var(axis=0, ddof=1) / stack.shape[0]
    centre = np.median(stack, axis=0)
    floor = np.maximum(centre, np.minimum(mean, 0.5 * max_filter3(centre)))
    outlier = mean > OUTLIER * floor
    light = outlier & (max_neighbour(mean) >= CORROBORATION * mean)
    denominator = np.where(light, mean, floor) ** 2 + eps
    terms = variance / denominator
    as_light = variance / (np.maximum(floor, mean) ** 2 + eps)
    return mean, variance, floor, terms, as_light, denominator


def estimated_terms(parts: Images, eps: float = REL_EPSILON) -> np.ndarray:
    """Per pixel and channel, the error terms :func:`estimate_rel_mse` averages (before spot
    checks): the variance of the parts' mean over its estimated denominator, float64
    (H, W, 3). Each pixel's parts need equal sample counts, not every pixel the same."""
    return _readings(_parts(parts), eps)[3]


def rel_denominators(parts: Images, eps: float = REL_EPSILON) -> np.ndarray:
    """Per pixel and channel, ``mu^2 + eps`` (the relative MSE's denominator) estimated from
    independent ``parts`` as :func:`estimate_rel_mse` does: robust to a firefly in one part,
    not to a light the parts saw."""
    return _readings(_parts(parts), eps)[5]


def estimate_rel_mse(
    parts: Images, eps: float = REL_EPSILON, checks: SpotChecks | None = None
) -> float | None:
    """The relative MSE of the mean of ``parts`` estimated without a reference, or None when
    the parts (and spot checks) cannot tell it yet.

    ``parts`` is a sequence (or a (K, H, W, 3) array) of K >= 3 independent images, each the
    mean of equal numbers of samples over disjoint sample ranges. Per pixel and channel:

    - the numerator, the sample variance of the parts over K, is an unbiased estimate of the
      variance of their mean ``m`` (its expected squared error when the renderer is unbiased);
    - the denominator estimates ``mu^2`` by the parts' median, which an outlier in one part
      does not reach (``m`` does: a firefly would count as a ~100% error whatever its size),
      floored by half the largest median of the 3x3 neighbourhood, never above ``m`` (a pixel
      at the rim of a small bright light, whose parts mostly missed it, beside pixels whose
      parts all saw it).

    An *outlier pixel* (``m`` above ``OUTLIER`` times that denominator) can be read two
    ways: a rare firefly on top of the pixel's value (the median is right), or the pixel's
    value itself, found by few samples (a light smaller than a pixel, seen directly, or a
    glint of the sun: ``m`` is right). Fireflies land at random, lights are where they are:
    an outlier pixel with a neighbour whose mean is at least ``CORROBORATION`` of its own is
    read as a light (``m``), the others as fireflies. A small light may still show in one
    pixel alone; when reading the ``UNRESOLVED_PIXELS`` pixels whose reading matters most
    the other way would change the relative error by more than ``AMBIGUITY``, the parts
    cannot tell it yet and the estimate is None.

    ``checks`` (:func:`pixels_to_check`, rendered by ``tracer.accuracy.spot_check``) replace the
    readings of their pixels by a measurement: with ``r`` the checks' mean and ``v`` its
    variance, ``(m - r)^2 - v`` is an unbiased estimate of ``(m - mu)^2``, this render's
    squared error there, and ``r^2 + 3 v`` in the denominator removes the first-order bias of
    ``1 / r^2`` (delta method), large where a pixel's value comes from rare samples. Checked
    pixels no longer count as ambiguous, unless the check itself is carried by one of its
    parts (its mean above ``OUTLIER`` times its median, or ``sqrt(eps)``): a path so rare that
    the check saw it once or not at all tells neither reading, so the pixel keeps its reading
    from the render's parts.

    It estimates the error of this render (which fireflies it caught), not the mean error of
    renders like it; docs/accuracy.md measures both.
    """
    stack = _parts(parts)
    mean, _, _, terms, as_light, _ = _readings(stack, eps)
    excess = (terms - as_light).sum(axis=2)
    if checks is not None and len(checks.pixels):
        samples = np.asarray(checks.parts, dtype=np.float64)
        value = samples.mean(axis=0)
        # A check carried by one of its parts has not resolved its pixel either.
        settled = (value <= OUTLIER * np.maximum(np.median(samples, axis=0), eps**0.5)).all(1)
        ys, xs = np.asarray(checks.pixels)[settled].T
        value, samples = value[settled], samples[:, settled]
        variance = samples.var(axis=0, ddof=1) / samples.shape[0]
        squared = value * value + 3.0 * variance  # E[1 / r^2] ~ (1 + 3 v / mu^2) / mu^2
        terms[ys, xs] = ((mean[ys, xs] - value) ** 2 - variance) / (squared + eps)
        excess[ys, xs] = 0.0
    total = max(0.0, float(terms.sum()))
    unresolved = np.sort(excess, axis=None)[-UNRESOLVED_PIXELS:].sum()
    if total - unresolved < total / AMBIGUITY**2:
        return None
    return total / terms.size


def estimate_rel_error(
    parts: Images, eps: float = REL_EPSILON, checks: SpotChecks | None = None
) -> float | None:
    """The relative RMS error of the mean of ``parts``: the square root of
    :func:`estimate_rel_mse` (None when that is None)."""
    mse = estimate_rel_mse(parts, eps, checks)
    return None if mse is None else float(np.sqrt(mse))


def _parts(parts: Images) -> np.ndarray:
    stack = np.asarray(parts, dtype=np.float64)
    if stack.ndim != 4 or stack.shape[3] != 3 or stack.shape[0] < 3:
        raise ValueError(
            f"expected at least 3 (H, W, 3) images of one shape, got shape {stack.shape}"
        )
    return stack


def max_neighbour(image: np.ndarray) -> np.ndarray:
    """The largest value of each pixel's 8 neighbours, per channel (-inf beyond the edges)."""
    padded = np.pad(image, ((1, 1), (1, 1), (0, 0)), constant_values=-np.inf)
    h, w = image.shape[:2]
    out = np.full(image.shape, -np.inf)
    for dy, dx in ((0, 0), (0, 1), (0, 2), (1, 0), (1, 2), (2, 0), (2, 1), (2, 2)):
        np.maximum(out, padded[dy : dy + h, dx : dx + w], out=out)
    return out


def max_filter3(image: np.ndarray) -> np.ndarray:
    """The largest value of each pixel's 3x3 neighbourhood (edges repeated), per channel."""
    padded = np.pad(image, ((1, 1), (1, 1), (0, 0)), mode="edge")
    h, w = image.shape[:2]
    out = padded[1 : h + 1, 1 : w + 1].copy()
    for dy in range(3):
        for dx in range(3):
            np.maximum(out, padded[dy : dy + h, dx : dx + w], out=out)
    return out

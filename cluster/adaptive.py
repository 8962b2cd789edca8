"""Adaptive sampling in progressive frames: how many of a wave's samples each pixel takes,
from the earlier waves' parts (``docs/accuracy.md``, "Adaptive sampling").

A pixel's estimated error term ``t`` (``tracer.accuracy.error_estimate.estimated_terms``,
summed over its channels) times its samples ``N`` is its relative variance per sample ``r``;
for a given number of samples the relative MSE, the mean of ``r / N``, is least with ``N``
proportional to ``sqrt(r)``. Four parts give ``r`` with three degrees of freedom, so it is
smoothed: the mean of each 3x3 neighbourhood, then the largest such mean around each pixel (a
pixel beside a noisy one samples as it does). A pixel's *rate* is ``sqrt`` of that over its
mean over the image, clipped to ``[MIN_RATE, MAX_RATE]``: the wave's samples are shared out,
not only cut where the noise is low. A wave of ``s`` samples per part on average gives it
``ceil(rate * s)`` of them (at least 1: every part keeps every pixel), the first ones of the
part's sample range, which is as long as the most any pixel takes; sample indices stay
disjoint across parts and waves.

Every step is element-wise float64 arithmetic or an exactly rounded sum (``math.fsum``) of
pixels that are the same bits however the frame was split: the counts are the same on any CPU
and for any split, and depend on the earlier waves' pixels only.

``auto`` samples adaptively only where it is predicted to win: the relative MSE at equal
samples, ``mean(r) / (mean(r / rate) * mean(rate))``, at least ``AUTO_GAIN`` times lower.
"""

import math

import numpy as np

from tracer.accuracy.error_estimate import estimated_terms, max_filter3
from tracer.integrators.names import ADAPTIVE as MODES

MIN_RATE = 1 / 8
"""Fewest of a wave's samples a pixel takes, as a share of the wave's mean."""
MAX_RATE = 16.0
"""Most of a wave's samples a pixel takes, as a multiple of the wave's mean."""
AUTO_GAIN = 1.2
"""Least predicted gain (relative MSE at equal samples) at which ``auto`` is adaptive."""
START_PART_SPP = 2
"""Samples per part every pixel has before the first adaptive wave."""


def per_sample_variance(parts: np.ndarray, part_counts: np.ndarray) -> np.ndarray:
    """``r``: each pixel's relative variance per sample, float64 (H, W), from its ``parts``
    (PARTS, H, W, 3) of ``part_counts`` (H, W) samples each."""
    t = estimated_terms(parts)
    return (t[..., 0] + t[..., 1] + t[..., 2]) * (parts.shape[0] * part_counts)


def _box3(image: np.ndarray) -> np.ndarray:
    """The mean of each pixel's 3x3 neighbourhood (edges repeated), summed in a fixed order."""
    padded = np.pad(image, 1, mode="edge")
    h, w = image.shape
    total = np.zeros(image.shape)
    for dy in range(3):
        for dx in range(3):
            total = total + padded[dy : dy + h, dx : dx + w]
    return total / 9.0


def sample_rates(r: np.ndarray) -> np.ndarray | None:
    """Each pixel's rate (H, W) in ``[MIN_RATE, MAX_RATE]``, about 1 on average, from its
    variance per sample ``r`` (:func:`per_sample_variance`), or None when nothing is noisy."""
    noise = np.sqrt(max_filter3(_box3(r)[..., None])[..., 0])
    scale = mean(noise)
    if not scale > 0.0:
        return None
    return np.clip(noise / scale, MIN_RATE, MAX_RATE)


def mean(values: np.ndarray) -> float:
    """The mean, exactly rounded (the same whatever the order or the CPU)."""
    return math.fsum(np.asarray(values, np.float64).ravel()) / max(1, np.size(values))


def predicted_gain(r: np.ndarray, rates: np.ndarray) -> float:
    """How many times lower the relative MSE is with ``rates`` than uniform at equal samples,
    if ``r`` held: ``mean(r) / (mean(r / rates) * mean(rates))``."""
    weighted = mean(r / rates) * mean(rates)
    return mean(r) / weighted if weighted > 0.0 else 1.0


def next_rates(
    mode: str, parts: np.ndarray, part_counts: np.ndarray, part_spp: int
) -> np.ndarray | None:
    """The rates of the next wave in ``mode`` (``MODES``) of a frame whose ``parts`` (PARTS,
    H, W, 3) have ``part_counts`` (H, W) samples each, at most ``part_spp`` (the sample range); None
    for a uniform wave."""
    if mode not in MODES:
        raise ValueError(f"adaptive must be one of {', '.join(MODES)}, got {mode!r}")
    if mode == "off" or part_spp < START_PART_SPP:
        return None
    r = per_sample_variance(parts, part_counts)
    rates = sample_rates(r)
    if rates is None or (mode == "auto" and predicted_gain(r, rates) < AUTO_GAIN):
        return None
    return rates


def wave_counts(rates: np.ndarray, spp: int) -> np.ndarray:
    """Samples per part of each pixel (int32, row-major) in a wave of ``spp`` per part on
    average."""
    return np.maximum(np.ceil(rates * spp), 1).astype(np.int32).reshape(-1)

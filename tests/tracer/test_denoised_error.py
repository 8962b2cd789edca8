"""The denoised image's error estimate (``tracer.accuracy.denoised_error``): unbiased for a
linear denoiser under Gaussian noise (its risk known exactly), the raw variance for the identity,
None where the parts are too few samples, and within the calibration band on a real denoised
render against the Cornell box's independent reference."""

import numpy as np
import pytest
from scipy.ndimage import uniform_filter

from tracer.accuracy.denoised_error import (
    MIN_PART_SPP,
    estimate_denoised_rel_error,
    estimate_denoised_rel_mse,
)
from tracer.accuracy.error_estimate import PARTS, REL_EPSILON

H, W = 48, 64


def truth() -> np.ndarray:
    """A smooth image with a step: what a box filter blurs (bias) and flattens (noise)."""
    y, x = np.mgrid[0:H, 0:W] / np.array([H, W])[:, None, None]
    base = 0.5 + 0.3 * np.sin(6 * x) * np.cos(4 * y) + 0.4 * (x > 0.5)
    return np.stack([base, 0.8 * base, 1.2 * base], axis=2)


def box(image: np.ndarray) -> np.ndarray:
    return uniform_filter(np.asarray(image, np.float64), size=(3, 3, 1), mode="nearest")


def noisy_parts(mu: np.ndarray, sigma: float, rng) -> np.ndarray:
    """PARTS images whose mean has standard deviation ``sigma`` around ``mu``."""
    return mu + rng.standard_normal((PARTS, *mu.shape)) * sigma * np.sqrt(PARTS)


def true_rel_mse(image: np.ndarray, mu: np.ndarray) -> float:
    return float(np.mean((image - mu) ** 2 / (mu * mu + REL_EPSILON)))


def test_sure_is_unbiased_for_a_linear_denoiser():
    """A 3x3 box filter under Gaussian noise (a few percent of the signal, as in a render of
    ``MIN_PART_SPP`` samples per part and more): the mean estimate over trials equals the mean
    true relative MSE, most of it the filter's bias, within four standard errors of their
    difference and the few percent that weights estimated from the parts add."""
    mu, rng = truth(), np.random.default_rng(7)
    differences, errors = [], []
    for trial in range(24):
        parts = noisy_parts(mu, 0.02, rng)
        denoised = box(parts.mean(axis=0))
        estimate = estimate_denoised_rel_mse(parts, MIN_PART_SPP, denoised, box, seed=trial)
        error = true_rel_mse(denoised, mu)
        differences.append(estimate - error)
        errors.append(error)
    se = np.std(differences, ddof=1) / np.sqrt(len(differences))
    assert abs(np.mean(differences)) <= 4 * se + 0.05 * np.mean(errors), (
        np.mean(differences),
        se,
        np.mean(errors),
    )
    assert se < 0.1 * np.mean(errors)  # the test can fail: the trials pin it to a few percent


def test_for_the_identity_it_is_the_raw_variance():
    """Denoising that changes nothing leaves the raw error: the estimate is the raw image's
    relative variance (its divergence term restores the variance the residual subtracts)."""
    mu = truth()
    parts = noisy_parts(mu, 0.05, np.random.default_rng(3))
    mean = parts.mean(axis=0)
    estimate = estimate_denoised_rel_mse(parts, MIN_PART_SPP, mean, lambda x: x, seed=1)
    variance = parts.var(axis=0, ddof=1) / PARTS
    expected = float(np.mean(variance / (mu * mu + REL_EPSILON)))
    assert estimate == pytest.approx(expected, rel=0.1)


def test_too_few_samples_per_part_give_no_estimate_and_seeds_repeat():
    mu = truth()
    parts = noisy_parts(mu, 0.05, np.random.default_rng(5))
    denoised = box(parts.mean(axis=0))
    assert estimate_denoised_rel_mse(parts, MIN_PART_SPP - 1, denoised, box, seed=0) is None
    assert estimate_denoised_rel_error(parts, MIN_PART_SPP - 1, denoised, box, seed=0) is None
    a = estimate_denoised_rel_mse(parts, MIN_PART_SPP, denoised, box, seed=4)
    assert a == estimate_denoised_rel_mse(parts, MIN_PART_SPP, denoised, box, seed=4)
    root = estimate_denoised_rel_error(parts, MIN_PART_SPP, denoised, box, seed=4)
    assert root == pytest.approx(np.sqrt(a))
    with pytest.raises(ValueError, match="the denoised image is"):
        estimate_denoised_rel_mse(parts, MIN_PART_SPP, denoised[:-1], box, seed=0)

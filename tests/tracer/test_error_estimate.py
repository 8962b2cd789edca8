"""Error metrics against a reference, and the estimate of a render's error from two half
images: exact values on small hand-made images, and statistical checks with fixed seeds whose
tolerances come from the number of pixels. The estimate's calibration on real renders is in
``tests/cli/test_accuracy.py``."""

import math

import numpy as np
import pytest

from tracer.error_estimate import (
    REL_EPSILON,
    estimate_rel_error,
    estimate_rel_mse,
    max_filter3,
    noise_floor,
    psnr,
    rel_mse,
    rmse,
    to_display,
)

SHAPE = (48, 64, 3)


def test_rel_mse_by_hand():
    ref = np.zeros((1, 2, 3))
    ref[0, 0] = 1.0
    x = ref.copy()
    x[0, 0, 0] = 1.5  # (0.5^2) / (1 + eps)
    x[0, 1, 2] = 0.1  # (0.1^2) / (0 + eps)
    expected = (0.25 / (1.0 + REL_EPSILON) + 0.01 / REL_EPSILON) / 6
    assert rel_mse(x, ref) == pytest.approx(expected, rel=1e-12)
    assert rel_mse(ref, ref) == 0.0
    assert rmse(x, ref) == pytest.approx(math.sqrt((0.25 + 0.01) / 6), rel=1e-12)


def test_rel_mse_is_relative():
    """Bright images: scaling image and reference together leaves the relative MSE (almost)
    unchanged, while the RMSE scales."""
    rng = np.random.default_rng(1)
    ref = rng.uniform(5.0, 10.0, SHAPE)
    x = ref * (1.0 + rng.normal(0.0, 0.01, SHAPE))
    assert rel_mse(100 * x, 100 * ref) == pytest.approx(rel_mse(x, ref), rel=1e-3)
    assert rmse(100 * x, 100 * ref) == pytest.approx(100 * rmse(x, ref), rel=1e-9)


def test_psnr_of_display_images():
    """Display values 1.0 against 0.9 everywhere: MSE 0.01, PSNR 20 dB."""
    ref = np.ones(SHAPE)
    display = 0.9
    linear = ((display + 0.055) / 1.055) ** 2.4  # the inverse sRGB curve
    x = np.full(SHAPE, linear)
    assert to_display(x) == pytest.approx(display, rel=1e-12)
    assert psnr(x, ref) == pytest.approx(20.0, rel=1e-9)
    assert psnr(ref, ref) == math.inf
    assert psnr(5 * ref, ref) == math.inf  # both clip to white


def test_shapes_are_checked():
    with pytest.raises(ValueError, match="shape"):
        rel_mse(np.zeros((4, 4, 3)), np.zeros((4, 5, 3)))
    with pytest.raises(ValueError, match="shape"):
        estimate_rel_mse(np.zeros((4, 4)), np.zeros((4, 4)))


def test_noise_floor_removes_the_reference_noise():
    """An image and a noisy reference, independent: the measured relative MSE minus the floor
    estimates the image's own error against the truth. Both are means over P pixels of
    independent terms, so the tolerance is 4 standard errors of that mean."""
    rng = np.random.default_rng(2)
    truth = rng.uniform(0.5, 2.0, SHAPE)
    ref_var = (0.05 * truth) ** 2
    ref = truth + rng.normal(0.0, 1.0, SHAPE) * np.sqrt(ref_var)
    x = truth + rng.normal(0.0, 0.1, SHAPE) * truth
    terms = (x - ref) ** 2 / (ref**2 + REL_EPSILON) - ref_var / (ref**2 + REL_EPSILON)
    own = (x - truth) ** 2 / (ref**2 + REL_EPSILON)
    se = np.sqrt(terms.var() / terms.size + own.var() / own.size)
    corrected = rel_mse(x, ref) - noise_floor(ref, ref_var)
    assert abs(corrected - own.mean()) < 4 * se
    assert rel_mse(x, ref) - own.mean() > 4 * se  # without the floor, the error is too big


def test_max_filter3():
    image = np.zeros((4, 5, 3))
    image[0, 0, 0] = 1.0
    image[3, 2, 1] = 2.0
    out = max_filter3(image)
    assert out[:2, :2, 0].tolist() == [[1.0, 1.0], [1.0, 1.0]]
    assert out[2:, 1:4, 1].tolist() == [[2.0] * 3, [2.0] * 3]
    assert out.sum() == 4 * 1.0 + 6 * 2.0


def halves(rng, mean, sd_half):
    """Two independent Gaussian half images around ``mean``, each with per-pixel sd."""
    return (
        mean + rng.normal(0.0, 1.0, mean.shape) * sd_half,
        mean + rng.normal(0.0, 1.0, mean.shape) * sd_half,
    )


@pytest.mark.parametrize("relative_sd", [0.005, 0.01, 0.02])
def test_estimate_matches_the_variance_of_the_mean(relative_sd):
    """Smooth, low noise (Gaussian halves): the estimate of the relative MSE of the mean is
    its expected value ``mean(Var(M) / (mu^2 + eps))``, Var(M) = sd^2 / 2, within 4 standard
    errors of a mean over P pixels (chi-square terms: sd sqrt(2) x mean), and above it by at
    most the first-order bias of the smaller half in the denominator (``E[min] = mu - sd /
    sqrt(pi)``, squared, plus its variance ``(1 - 1/pi) sd^2`` through Jensen's inequality)."""
    rng = np.random.default_rng(3)
    mu = rng.uniform(0.5, 2.0, SHAPE)
    sd = relative_sd * mu
    a, b = halves(rng, mu, sd)
    expected = (sd**2 / 2 / (mu**2 + REL_EPSILON)).mean()
    se = math.sqrt(2.0) * expected / math.sqrt(mu.size)
    bias = (1.0 - relative_sd / math.sqrt(math.pi)) ** -2 * (
        1.0 + 3.0 * (1.0 - 1.0 / math.pi) * relative_sd**2
    )
    got = estimate_rel_mse(a, b)
    assert expected - 4 * se <= got <= expected * bias + 4 * se
    assert estimate_rel_error(a, b) == pytest.approx(math.sqrt(got), rel=1e-12)


@pytest.mark.parametrize("relative_sd", [0.05, 0.1, 0.2])
def test_estimate_errs_high_within_30_percent(relative_sd):
    """Noisier halves (per-pixel error of the mean up to 14%): the smaller half in the
    denominator makes the estimated relative error too high, by less than 30%."""
    rng = np.random.default_rng(4)
    mu = rng.uniform(0.5, 2.0, SHAPE)
    a, b = halves(rng, mu, relative_sd * mu)
    ratio = estimate_rel_error(a, b) / math.sqrt(rel_mse(0.5 * (a + b), mu))
    assert 1.0 <= ratio <= 1.3


def test_estimate_follows_a_firefly():
    """A firefly in one half is an error of the mean of the halves; the mean's square in the
    denominator would hide it (every firefly counts ~100%), the smaller half does not."""
    mu = np.full(SHAPE, 0.5)
    a, b = mu.copy(), mu.copy()
    a[10, 10] = 500.0
    m = 0.5 * (a + b)
    true = rel_mse(m, mu)
    plain = float(np.mean(0.25 * (a - b) ** 2 / (m * m + REL_EPSILON)))
    assert estimate_rel_mse(a, b) == pytest.approx(true, rel=1e-9)
    assert plain < 0.01 * true


def test_estimate_of_identical_halves_is_zero():
    a = np.random.default_rng(5).uniform(0.0, 1.0, SHAPE)
    assert estimate_rel_mse(a, a) == 0.0

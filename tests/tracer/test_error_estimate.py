"""Error metrics against a reference, and the estimate of a render's error from independent
parts: exact values on small hand-made images, and statistical checks with fixed seeds whose
tolerances come from the number of pixels. The estimate's calibration on real renders is in
``tests/cli/test_accuracy.py``."""

import math

import numpy as np
import pytest

from tracer.accuracy.error_estimate import (
    AMBIGUITY,
    PARTS,
    REL_EPSILON,
    SPOT_CHECKS,
    SpotChecks,
    estimate_rel_error,
    estimate_rel_mse,
    max_filter3,
    noise_floor,
    pixels_to_check,
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
    with pytest.raises(ValueError, match="at least 3"):
        estimate_rel_mse([np.zeros((4, 4, 3))] * 2)
    with pytest.raises(ValueError, match="shape"):
        estimate_rel_mse(np.zeros((4, 4, 4)))


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


def parts(rng, mean, sd_part, count=PARTS):
    """``count`` independent Gaussian part images around ``mean``, each with per-pixel sd."""
    return mean + rng.normal(0.0, 1.0, (count, *mean.shape)) * sd_part


@pytest.mark.parametrize("relative_sd", [0.005, 0.01, 0.02])
def test_estimate_matches_the_variance_of_the_mean(relative_sd):
    """Smooth, low noise (Gaussian parts): the estimate of the relative MSE of the mean is its
    expected value ``mean(Var(M) / (mu^2 + eps))``, Var(M) = sd^2 / K, within 4 standard
    errors of a mean over P pixels (chi-square terms with K - 1 degrees of freedom: sd
    sqrt(2 / (K - 1)) x mean), and above it by at most the Jensen bias of the median in the
    denominator (variance below 0.3 sd^2 for K = 4: a factor 1 + 3 x 0.3 x relative_sd^2)."""
    rng = np.random.default_rng(3)
    mu = rng.uniform(0.5, 2.0, SHAPE)
    sd = relative_sd * mu
    images = parts(rng, mu, sd)
    expected = (sd**2 / PARTS / (mu**2 + REL_EPSILON)).mean()
    se = math.sqrt(2.0 / (PARTS - 1)) * expected / math.sqrt(mu.size)
    got = estimate_rel_mse(images)
    assert expected - 4 * se <= got <= expected * (1.0 + 0.9 * relative_sd**2) + 4 * se
    assert estimate_rel_error(list(images)) == pytest.approx(math.sqrt(got), rel=1e-12)


@pytest.mark.parametrize("relative_sd", [0.05, 0.1, 0.2, 0.4])
def test_estimate_is_calibrated_at_high_noise(relative_sd):
    """Noisier parts (per-pixel error of the mean up to 20%): the median of the parts is an
    unbiased centre for symmetric noise, so the estimate stays within 10% of the true error
    (the old smaller-of-two-halves denominator was 23% high at a per-half sd of 20%)."""
    rng = np.random.default_rng(4)
    mu = rng.uniform(0.5, 2.0, SHAPE)
    images = parts(rng, mu, relative_sd * mu)
    ratio = estimate_rel_error(images) / math.sqrt(rel_mse(images.mean(axis=0), mu))
    assert 0.9 <= ratio <= 1.1, ratio


def test_estimate_follows_a_firefly():
    """A firefly in one part among noisy pixels is an error of the mean; the mean's square in
    the denominator would hide it (every firefly counts ~100%), the median does not: the
    estimate matches the true error of the mean within 4 standard errors of the other pixels,
    plus 25% of the firefly's part (its pixel's median is then the mean of the larger two of
    the other three parts: about 0.4 sd high, and noisy, with a part's sd of 10%)."""
    rng = np.random.default_rng(6)
    mu = np.full(SHAPE, 0.5)
    images = parts(rng, mu, 0.1 * mu)
    images[1, 10, 10] = 6.0
    mean = images.mean(axis=0)
    true = rel_mse(mean, mu)
    firefly = ((mean[10, 10] - mu[10, 10]) ** 2 / (0.25 + REL_EPSILON)).sum() / mu.size
    assert firefly > 0.4 * true  # the firefly is about half the error
    plain = np.mean(images.var(axis=0, ddof=1) / PARTS / (mean * mean + REL_EPSILON))
    assert plain < 0.6 * true
    se = math.sqrt(2.0 / (PARTS - 1)) * (true - firefly) / math.sqrt(mu.size)
    assert estimate_rel_mse(images) == pytest.approx(true, abs=4 * se + 0.25 * firefly)


def test_scattered_fireflies_are_estimated():
    """Fireflies in one part each, at pixels far apart, carrying nearly all the error: read
    with the mean as denominator they would count ~100% each (below 1/2.25 of the true error,
    where the former whole-image test said None); as fireflies over the median they are the
    error of the mean. Per firefly pixel the estimate is ``F^2 / 16`` over the median of the
    three other parts, which lies at most about one part's sd (2%) above ``mu``: the
    denominator is at most ~4% high, so the estimate is within 6% of the true error."""
    rng = np.random.default_rng(8)
    mu = np.full(SHAPE, 0.5)
    images = parts(rng, mu, 0.02 * mu)
    ys, xs = np.meshgrid(np.arange(2, 48, 5), np.arange(2, 64, 5), indexing="ij")
    for y, x in zip(ys.ravel(), xs.ravel(), strict=True):
        images[rng.integers(PARTS), y, x] += rng.uniform(10.0, 40.0)
    mean = images.mean(axis=0)
    true = rel_mse(mean, mu)
    as_values = np.mean(images.var(axis=0, ddof=1) / PARTS / (mean * mean + REL_EPSILON))
    assert as_values < true / AMBIGUITY**2
    assert estimate_rel_mse(images) == pytest.approx(true, rel=0.06)


def test_a_small_light_seen_in_one_part_per_pixel():
    """A light seen directly over a block of pixels, each of which only one part happened to
    sample it: the pixels' means corroborate each other, so they are read as the light's
    value (denominator the mean, exactly), not as fireflies (which would count them ~100 times
    more); one such pixel alone is not estimable (below)."""
    rng = np.random.default_rng(9)
    mu = np.full(SHAPE, 0.5)
    images = parts(rng, mu, 0.02 * mu)
    block = (slice(20, 23), slice(30, 34))
    images[(rng.integers(PARTS, size=(3, 4)), *np.ogrid[20:23, 30:34])] += 20.0
    variance = images.var(axis=0, ddof=1) / PARTS
    mean = images.mean(axis=0)
    centre = np.median(images, axis=0)
    denominator = np.maximum(centre, np.minimum(mean, 0.5 * max_filter3(centre)))
    denominator[block] = mean[block]
    expected = np.mean(variance / (denominator**2 + REL_EPSILON))
    assert estimate_rel_mse(images) == pytest.approx(expected, rel=1e-12)
    as_fireflies = variance[block] / (centre[block] ** 2 + REL_EPSILON)
    assert as_fireflies.sum() > 50 * (variance[block] / (mean[block] ** 2 + REL_EPSILON)).sum()


def test_an_outlier_that_carries_the_error_is_not_estimable():
    """A pixel that one part alone saw lit (a light smaller than a pixel, or a firefly on a
    black pixel), with no lit neighbour, that makes most of the image's error: the parts
    cannot tell whether it is a rare outlier or the pixel's value, so the estimate is None;
    the same with two such pixels far apart; once the other parts see it too, it is an
    estimate again."""
    rng = np.random.default_rng(7)
    mu = np.full(SHAPE, 0.5)
    images = parts(rng, mu, 0.05 * mu)
    images[:, 20, 30] = 0.0
    images[2, 20, 30] = 40.0
    assert estimate_rel_mse(images) is None
    assert estimate_rel_error(images) is None
    two = images.copy()
    two[:, 20, 30] = 0.5
    two[1, 5, 5] = two[3, 40, 60] = 30.0
    assert estimate_rel_mse(two) is None
    images[:, 20, 30] = np.array([38.0, 41.0, 40.0, 0.0])[:, None]
    assert estimate_rel_mse(images) is not None


def test_estimate_of_identical_parts_is_zero():
    a = np.random.default_rng(5).uniform(0.0, 1.0, SHAPE)
    assert estimate_rel_mse([a, a, a, a]) == 0.0


def checks_of(pixels, value, sd, rng, count=PARTS) -> SpotChecks:
    """Spot checks of ``pixels`` whose parts are Gaussian around ``value`` (per pixel) with
    per-part sd ``sd``."""
    pixels = np.asarray(pixels).reshape(-1, 2)
    value = np.broadcast_to(np.asarray(value, float), (len(pixels), 3))
    return SpotChecks(pixels, value + rng.normal(0.0, 1.0, (count, len(pixels), 3)) * sd)


def test_pixels_to_check_are_the_ambiguous_ones():
    """The pixels whose parts disagree most come first: one part lit (an outlier), two parts
    lit (not an outlier: the median is half lit). Ordinary noise (1% per part) leaves gaps
    below CHECK_GAP of the image's error everywhere else: no other pixel is worth a check,
    and a noiseless image needs none."""
    rng = np.random.default_rng(10)
    mu = np.full(SHAPE, 0.5)
    images = parts(rng, mu, 0.01 * mu)
    images[2, 20, 30] += 40.0
    images[[0, 3], 5, 7] += 10.0
    assert pixels_to_check(images, SPOT_CHECKS).tolist() == [[20, 30], [5, 7]]
    assert pixels_to_check(images, 1).tolist() == [[20, 30]]
    assert pixels_to_check(parts(rng, mu, 0.01 * mu), SPOT_CHECKS).shape == (0, 2)
    flat = np.full((PARTS, *SHAPE), 0.5)
    assert pixels_to_check(flat, SPOT_CHECKS).shape == (0, 2)


@pytest.mark.parametrize("value", [0.5, 10.0], ids=["firefly", "light"])
def test_spot_checks_tell_a_firefly_from_a_light(value):
    """One part saw a pixel lit, nothing else did: not estimable from the parts alone (see
    above). A spot check that finds the pixel's value tells which it was: a firefly on a 0.5
    pixel (the error is the firefly's) or a light smaller than a pixel worth 10 (the mean,
    40 / 4, is about right). Either way the estimate then matches the true error of the
    mean: within 4 standard errors of the other pixels' terms plus the check's own noise
    (sd 1% of the value, a relative error of at most ~2% of the pixel's term)."""
    rng = np.random.default_rng(11)
    mu = np.full(SHAPE, 0.5)
    mu[20, 30] = value
    images = parts(rng, np.full(SHAPE, 0.5), 0.05 * 0.5)
    images[:, 20, 30] = 0.0
    images[2, 20, 30] = 40.0
    assert estimate_rel_mse(images) is None
    pixels = pixels_to_check(images, 4)
    assert pixels[0].tolist() == [20, 30]
    checks = checks_of(pixels, mu[tuple(pixels.T)], 0.01 * mu[tuple(pixels.T)], rng)
    mean = images.mean(axis=0)
    true = rel_mse(mean, mu)
    pixel = float(((mean[20, 30] - value) ** 2 / (value**2 + REL_EPSILON)).sum()) / mu.size
    others = true - pixel
    se = math.sqrt(2.0 / (PARTS - 1)) * others / math.sqrt(mu.size)
    assert estimate_rel_mse(images, checks=checks) == pytest.approx(true, abs=4 * se + 0.03 * pixel)


def test_spot_checks_are_unbiased():
    """Every pixel checked, Gaussian render and checks: each checked term ``((m - r)^2 - v) /
    (r^2 + 3v + eps)`` estimates ``(m - mu)^2 / (mu^2 + eps)`` of this render, so the estimate
    matches the true error of this render (not only its expected error) within 4 standard
    errors of the mean of the per-pixel differences, with checks 8 times less noisy than the
    render."""
    rng = np.random.default_rng(12)
    mu = rng.uniform(0.5, 2.0, SHAPE)
    images = parts(rng, mu, 0.1 * mu)
    mean = images.mean(axis=0)
    ys, xs = np.indices(SHAPE[:2])
    pixels = np.stack([ys.ravel(), xs.ravel()], axis=1)
    value = mu[ys.ravel(), xs.ravel()]
    checks = checks_of(pixels, value, 0.1 * value / 8, rng)
    samples = checks.parts
    r, v = samples.mean(axis=0), samples.var(axis=0, ddof=1) / PARTS
    m = mean[ys.ravel(), xs.ravel()]
    estimated_terms = ((m - r) ** 2 - v) / (r * r + 3 * v + REL_EPSILON)
    true_terms = (m - value) ** 2 / (value**2 + REL_EPSILON)
    se = (estimated_terms - true_terms).std() / math.sqrt(true_terms.size)
    got = estimate_rel_mse(images, checks=checks)
    assert got == pytest.approx(estimated_terms.mean(), rel=1e-9)
    assert abs(got - rel_mse(mean, mu)) < 4 * se


def test_spot_checks_are_validated():
    with pytest.raises(ValueError, match="pixels"):
        SpotChecks(np.zeros((3,), int), np.zeros((PARTS, 3, 3)))
    with pytest.raises(ValueError, match="parts"):
        SpotChecks(np.zeros((2, 2), int), np.zeros((PARTS, 3, 3)))
    with pytest.raises(ValueError, match="parts"):
        SpotChecks(np.zeros((2, 2), int), np.zeros((1, 2, 3)))


def test_a_check_carried_by_one_part_settles_nothing():
    """A check that saw the pixel's rare bright path in one of its parts only (a path rarer
    than the check's samples) cannot tell the pixel's value either: the pixel keeps its
    reading from the render's parts, and the estimate stays not estimable, as without it."""
    rng = np.random.default_rng(13)
    images = parts(rng, np.full(SHAPE, 0.5), 0.05 * 0.5)
    images[:, 20, 30] = 0.0
    images[2, 20, 30] = 40.0
    pixels = np.array([[20, 30]])
    carried = SpotChecks(pixels, np.array([0.5, 0.5, 0.5, 30.0])[:, None, None] * np.ones(3))
    assert estimate_rel_mse(images, checks=carried) is None
    settled = SpotChecks(pixels, np.array([0.5, 0.6, 0.45, 0.55])[:, None, None] * np.ones(3))
    assert estimate_rel_mse(images, checks=settled) is not None

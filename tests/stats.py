"""Statistical comparison of a render with a reference: per-pixel Welch tests.

Both images are means of independent passes with a known variance of the mean: ours from the
spread of K passes (K - 1 degrees of freedom), the reference's stored beside it (16 passes,
15 degrees of freedom). For each pixel and channel,

    t = (mean_ours - mean_ref) / sqrt(var_ours + var_ref)

is compared with Student's t at the Welch-Satterthwaite degrees of freedom (not with the normal
distribution: with variances estimated from few passes the normal test rejects far too often).
A pixel is accepted when its three channels all accept; the per-channel level is Sidak-corrected
for three channels, and the per-pixel level for the number of pixels (Mitsuba's render tests do
the same), so that under the null hypothesis a false rejection anywhere in the image has
probability ``alpha``. Pixels with zero variance on both sides accept only if exactly equal.
"""

from dataclasses import dataclass

import numpy as np
from scipy import stats


@dataclass
class PixelTest:
    """Outcome of :func:`welch_pixel_test`."""

    accepted_fraction: float
    """Fraction of pixels accepted at the Sidak-corrected level."""
    uncorrected_rejected_fraction: float
    """Fraction of pixels rejected at the plain per-pixel level alpha (about alpha under H0)."""
    p_values: np.ndarray
    """Smallest per-channel p-value of each pixel, shape (H, W)."""
    alpha_pixel: float


def sidak(alpha: float, tests: int) -> float:
    """Per-test level that keeps the family-wise error of ``tests`` independent tests at alpha."""
    return -np.expm1(np.log1p(-alpha) / tests)


def pass_statistics(passes: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """Mean, variance of the mean and degrees of freedom from K independent passes (K, H, W, 3)."""
    k = passes.shape[0]
    passes = passes.astype(np.float64)
    return passes.mean(axis=0), passes.var(axis=0, ddof=1) / k, k - 1


def welch_pixel_test(
    mean_a: np.ndarray,
    var_a: np.ndarray,
    dof_a: int,
    mean_b: np.ndarray,
    var_b: np.ndarray,
    dof_b: int,
    alpha: float = 0.01,
) -> PixelTest:
    """Per-pixel two-sample Welch t-test of two (H, W, 3) means with variances of the mean."""
    mean_a = mean_a.astype(np.float64)
    mean_b = mean_b.astype(np.float64)
    var_a = var_a.astype(np.float64)
    var_b = var_b.astype(np.float64)
    var = var_a + var_b
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.abs(mean_a - mean_b) / np.sqrt(var)
        dof = var**2 / (var_a**2 / dof_a + var_b**2 / dof_b)
    p = np.where(var > 0.0, 2.0 * stats.t.sf(t, np.where(var > 0.0, dof, 1.0)), 0.0)
    p = np.where((var == 0.0) & (mean_a == mean_b), 1.0, p)
    p_pixel = p.min(axis=2)
    n_pixels = p_pixel.size
    alpha_channel_pixel = sidak(alpha, 3)
    alpha_pixel = sidak(alpha, n_pixels)
    corrected = sidak(alpha_pixel, 3)
    return PixelTest(
        accepted_fraction=float((p_pixel >= corrected).mean()),
        uncorrected_rejected_fraction=float((p_pixel < alpha_channel_pixel).mean()),
        p_values=p_pixel,
        alpha_pixel=alpha_pixel,
    )

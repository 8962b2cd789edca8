"""Image error against a reference, and the error of a render estimated without one.

Images are float (H, W, 3) linear radiance. Definitions (``docs/accuracy.md``):

- **relative MSE**: the mean over pixels and channels of ``(x - ref)^2 / (ref^2 + eps)``, with
  ``eps = REL_EPSILON``; the **relative error** is its square root (relative RMS error);
- **RMSE**: the root mean square difference in linear radiance;
- **PSNR**: ``10 log10(1 / MSE)`` of the display images (clamped to [0, 1], sRGB-encoded);
- the **noise floor** of a reference with per-pixel variance ``var``: the relative MSE that
  the reference's own noise adds, on average, to any image compared with it.

The online estimate (:func:`estimate_rel_mse`) needs no reference: a render split into two
independent halves A and B of equal sample counts (disjoint sample ranges) has the mean
``M = (A + B) / 2``, and per pixel ``E[((A - B) / 2)^2] = Var(M)``, the expected squared error
of an unbiased ``M``; the function's docstring explains its denominator.
"""

import numpy as np

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


def estimate_rel_mse(a: np.ndarray, b: np.ndarray, eps: float = REL_EPSILON) -> float:
    """The relative MSE of ``(a + b) / 2`` estimated from two independent half images ``a``
    and ``b`` (means of equal numbers of samples over disjoint sample ranges), no reference.

    Per pixel and channel the numerator ``((a - b) / 2)^2`` is an unbiased estimate of the
    variance of the mean ``m = (a + b) / 2``. The denominator estimates ``mu^2``:

    - ``m^2`` would be biased high (``E[m^2] = mu^2 + Var(m)``) and, worse, grows with the very
      outlier that makes the numerator large: a firefly in one half then counts as an error of
      about 100% whatever its size. Measured on the sample scenes, that estimate fell to 0.1-0.5
      of the true error on scenes with caustics (docs/accuracy.md).
    - We take instead the smaller half, ``min(a, b)``, which a one-sided outlier does not
      reach, floored by half the largest ``min(a, b)`` of the 3x3 neighbourhood (but never
      above ``m``), so that a pixel where one half saw nothing yet, beside pixels where both
      saw light (the edge of a small bright light), is not measured against ``eps`` alone.

    The smaller half is biased low where a pixel's noise is comparable to its mean (few
    samples), so the estimate errs high there: the stopping rule then takes more samples than
    needed rather than fewer.
    """
    a, b = _pair(a, b)
    smaller = np.minimum(a, b)
    mu = np.maximum(smaller, np.minimum(0.5 * (a + b), 0.5 * max_filter3(smaller)))
    return float(np.mean(0.25 * (a - b) ** 2 / (mu * mu + eps)))


def estimate_rel_error(a: np.ndarray, b: np.ndarray, eps: float = REL_EPSILON) -> float:
    """The relative RMS error of ``(a + b) / 2``: the square root of :func:`estimate_rel_mse`."""
    return float(np.sqrt(estimate_rel_mse(a, b, eps)))


def max_filter3(image: np.ndarray) -> np.ndarray:
    """The largest value of each pixel's 3x3 neighbourhood (edges repeated), per channel."""
    padded = np.pad(image, ((1, 1), (1, 1), (0, 0)), mode="edge")
    h, w = image.shape[:2]
    out = padded[1 : h + 1, 1 : w + 1].copy()
    for dy in range(3):
        for dx in range(3):
            np.maximum(out, padded[dy : dy + h, dx : dx + w], out=out)
    return out

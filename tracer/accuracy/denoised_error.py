"""The error of a denoised image estimated without a reference: Stein's unbiased risk estimate.

A denoiser's error is as much bias (detail blurred away, a highlight spread) as left-over noise,
and the spread of a render's independent parts, which estimates the raw image's error
(``tracer.accuracy.error_estimate``), sees neither. SURE (Stein 1981; with a Monte Carlo
divergence for a black-box denoiser, Ramani, Blu and Unser 2008; used for rendering by Li, Wu
and Chuang 2012) sees both. For the render's mean ``m`` of independent parts, per pixel and
channel of variance ``s^2`` (estimated from the parts), and a denoiser ``D``:

    E[(D(m) - mu)^2] = E[(D(m) - m)^2 - s^2 + 2 s^2 dD(m)/dm]

where ``mu`` is the render's expectation and ``dD/dm`` the denoiser's response at a pixel to its
own input there. The response is measured by one more denoising: with ``b`` of independent unit
normal entries and a small ``e``, ``s^2 dD/dm ~ s b (D(m + e s b) - D(m)) / e`` summed over the
image. Each term is weighted by ``1 / (mu^2 + eps)`` of the relative MSE, with ``mu^2``
estimated from the parts as the raw estimate does (``rel_denominators``).

It assumes Gaussian noise and fixed guides. A path tracer's noise is far from Gaussian at a few
samples per part (the variance of four parts of one sample each says little), so the estimate
is given only from ``MIN_PART_SPP`` samples per part on; ``docs/accuracy.md`` calibrates it
against the references.
"""

from collections.abc import Callable

import numpy as np

from tracer.accuracy.error_estimate import REL_EPSILON, Images, _parts, rel_denominators

MIN_PART_SPP = 16
"""Fewest samples per part at which the estimate is given."""
PERTURBATION = 0.5
"""``e``: the probe's size in units of each pixel's standard deviation."""


def estimate_denoised_rel_mse(
    parts: Images,
    part_spp: int,
    denoised: np.ndarray,
    denoise: Callable[[np.ndarray], np.ndarray],
    seed: int,
    eps: float = REL_EPSILON,
) -> float | None:
    """The relative MSE of ``denoised`` (``denoise`` of the mean of ``parts``, (K >= 2, H, W,
    3) independent images of ``part_spp`` samples per pixel each) against the render's
    expectation, or None below ``MIN_PART_SPP``. ``denoise`` must denoise another beauty
    image as it did this one (the same quality and guides); it is called once, on the mean
    probed with normal noise from a generator seeded by ``seed``."""
    if part_spp < MIN_PART_SPP:
        return None
    stack = _parts(parts)
    mean = stack.mean(axis=0)
    sigma = np.sqrt(stack.var(axis=0, ddof=1) / stack.shape[0])
    d = np.asarray(denoised, dtype=np.float64)
    if d.shape != mean.shape:
        raise ValueError(f"the denoised image is {d.shape}, the parts' images {mean.shape}")
    weight = 1.0 / rel_denominators(stack, eps)
    probe = np.random.default_rng(seed).standard_normal(mean.shape)
    nudged = np.maximum(mean + PERTURBATION * sigma * probe, 0.0)
    response = np.asarray(denoise(nudged.astype(np.float32)), dtype=np.float64) - d
    divergence = (weight * sigma * probe * response).sum() / PERTURBATION
    residual = (weight * ((d - mean) ** 2 - sigma * sigma)).sum()
    return float((residual + 2.0 * divergence) / mean.size)


def estimate_denoised_rel_error(
    parts: Images,
    part_spp: int,
    denoised: np.ndarray,
    denoise: Callable[[np.ndarray], np.ndarray],
    seed: int,
    eps: float = REL_EPSILON,
) -> float | None:
    """The relative RMS error: the square root of :func:`estimate_denoised_rel_mse` (None
    when that is None or not positive: noise in the estimate, which then says nothing)."""
    mse = estimate_denoised_rel_mse(parts, part_spp, denoised, denoise, seed, eps)
    return None if mse is None or mse <= 0.0 else float(np.sqrt(mse))


def denoise_and_estimate(
    parts: Images,
    part_spp: int,
    albedo: np.ndarray | None,
    normal: np.ndarray | None,
    quality: str,
    prefilter: bool | tuple[str, ...],
    seed: int,
    threads: int | None = None,
) -> tuple[np.ndarray, float | None]:
    """The mean of ``parts`` denoised by Open Image Denoise (``tracer.post.denoise``) at
    ``quality`` with the guides given, and its estimated relative RMS error
    (:func:`estimate_denoised_rel_error`; None where it is not given): ``(image, error)``."""
    from tracer.post.denoise import denoise

    def run(beauty: np.ndarray) -> np.ndarray:
        done = denoise(beauty, albedo, normal, quality, threads, prefilter=prefilter)
        return done.image

    stack = _parts(parts)
    image = run(stack.mean(axis=0).astype(np.float32))
    return image, estimate_denoised_rel_error(stack, part_spp, image, run, seed)

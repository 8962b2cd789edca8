"""The accuracy study's metrics: an image against its reference (relative MSE, RMSE, PSNR,
SSIM, FLIP), and the time a sweep takes to reach a relative MSE (measured or extrapolated)."""

import math

import numpy as np

from cli.accuracy_reference import Reference
from tracer.accuracy.error_estimate import psnr, rel_mse_terms, rmse, to_display

TARGETS = (1e-2, 1e-3, 1e-4)
"""Relative MSEs whose time the study reports (relative RMS errors of 10%, 3.2% and 1%)."""
FIT_LEVELS = 4
"""Levels at the end of a sweep that fit ``bias + variance / N`` for extrapolation."""


def measure(image: np.ndarray, ref: Reference, floor: float, flip: bool) -> dict:
    """Every metric of ``image`` against the reference: ``rel_mse`` (the reference's noise floor
    subtracted), ``rel_mse_raw``, ``rel_mse_se`` (its standard error over pixels), ``rmse``
    (linear), ``psnr``, ``ssim`` (display images) and
    ``flip`` (LDR FLIP of the display images, or None when not asked for)."""
    from skimage.metrics import structural_similarity

    terms = rel_mse_terms(image, ref.mean).mean(axis=2)
    raw = float(terms.mean())
    shown, shown_ref = to_display(image), to_display(ref.mean)
    side = min(image.shape[:2])
    window = min(7, side if side % 2 else side - 1)
    return {
        "rel_mse": raw - floor,
        "rel_mse_raw": raw,
        "rel_mse_se": float(terms.std(ddof=1) / math.sqrt(terms.size)),
        "rmse": rmse(image, ref.mean),
        "psnr": psnr(image, ref.mean),
        "ssim": float(
            structural_similarity(shown, shown_ref, channel_axis=2, data_range=1.0, win_size=window)
        ),
        "flip": flip_error(shown, shown_ref) if flip else None,
    }


def flip_error(shown: np.ndarray, shown_ref: np.ndarray) -> float:
    """Mean LDR FLIP error of two sRGB display images in [0, 1]."""
    import flip_evaluator

    _, mean, _ = flip_evaluator.evaluate(
        shown_ref.astype(np.float32), shown.astype(np.float32), "LDR", applyMagma=False
    )
    return float(mean)


def time_to(levels: list[dict], target: float) -> dict:
    """Seconds and samples per pixel at which ``levels`` (a sweep's records, in order) first
    reach a relative MSE of ``target``: interpolated in log-log between the levels around it
    (``how``: ``measured``). Past the last level, the error is modelled as
    ``bias + variance / N`` (:func:`bias_variance`): if ``target`` lies above the bias, the
    samples the model needs, at the last level's seconds per sample (``extrapolated``); else
    ``not reached``. ``floor`` is the fitted bias (None when the target was measured)."""
    previous = None
    for level in levels:
        if level["rel_mse"] <= target:
            if previous is None or previous["rel_mse"] <= 0.0 or level["rel_mse"] <= 0.0:
                return _reached(level["seconds"], level["spp"], "measured")
            f = math.log(previous["rel_mse"] / target) / math.log(
                previous["rel_mse"] / level["rel_mse"]
            )
            return _reached(
                previous["seconds"] * (level["seconds"] / previous["seconds"]) ** f,
                previous["spp"] * (level["spp"] / previous["spp"]) ** f,
                "measured",
            )
        previous = level
    last = levels[-1]
    floor, _ = bias_variance(levels[-FIT_LEVELS:])
    if target <= floor:
        return {"seconds": None, "spp": None, "how": "not reached", "floor": floor}
    factor = (last["rel_mse"] - floor) / (target - floor)
    return {
        "seconds": last["seconds"] * factor,
        "spp": last["spp"] * factor,
        "how": "extrapolated",
        "floor": floor,
    }


def _reached(seconds: float, spp: float, how: str) -> dict:
    return {"seconds": seconds, "spp": spp, "how": how, "floor": None}


def bias_variance(levels: list[dict]) -> tuple[float, float]:
    """``(b, c)`` of ``rel_mse = b + c / spp`` fitted to ``levels`` by least squares on
    relative residuals: ``b`` is the (squared, relative) bias the configuration converges to,
    ``c / N`` its variance at N spp. ``b`` is clipped to [0, the last level's relative MSE]:
    an unbiased configuration fits a small ``b`` of either sign."""
    e = np.array([lv["rel_mse"] for lv in levels])
    n = np.array([lv["spp"] for lv in levels], dtype=np.float64)
    if len(levels) < 2 or np.any(e <= 0.0):
        return 0.0, float(e[-1] * n[-1])
    (b, c), *_ = np.linalg.lstsq(np.stack([1.0 / e, 1.0 / (n * e)], axis=1), np.ones(len(e)))
    return float(min(max(b, 0.0), e[-1])), float(c)


def refresh_time_to(results: dict) -> None:
    """Recompute every configuration's time to each target from its levels (after a change
    of :func:`time_to`, without rendering again)."""
    for scene in results["scenes"].values():
        for data in scene["configs"].values():
            data["time_to"] = {f"{t:g}": time_to(data["levels"], t) for t in TARGETS}

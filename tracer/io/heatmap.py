"""The per-pixel cost heat map (after Bikker, fig. 47): work per sample as a colour.

Cost is what the path kernel counts per pixel (BVH node visits plus triangle tests), divided by
the samples taken. It maps to ``t = log2(1 + cost) / log2(1 + COST_HEATMAP_MAX)`` (clamped to
[0, 1]), then through a fixed ramp blue - cyan - green - yellow - red. The scale is fixed, not
the image's maximum, so a pixel's colour depends on that pixel alone and heat maps of different
scenes and frames compare directly.
"""

import math

import numpy as np

from tracer import config
from tracer.kernel.jit import jit

RAMP = np.array(
    [
        [0.0, 0.0, 1.0],
        [0.0, 1.0, 1.0],
        [0.0, 1.0, 0.0],
        [1.0, 1.0, 0.0],
        [1.0, 0.0, 0.0],
    ]
)
"""Colours at t = 0, 1/4, 1/2, 3/4, 1 (linearly interpolated between)."""


@jit
def _log_scale(per_sample, out):
    """``log2(1 + x) / log2(1 + COST_HEATMAP_MAX)`` per element (the C library's ``log2``, not
    numpy's per-CPU SIMD)."""
    top = math.log2(1.0 + config.COST_HEATMAP_MAX)
    for i in range(per_sample.size):
        out[i] = math.log2(1.0 + per_sample[i]) / top


def cost_heatmap(cost: np.ndarray, spp: int) -> np.ndarray:
    """float32 (..., 3) colours for per-pixel costs ``cost`` (int, any shape) of ``spp`` samples."""
    per_sample = np.ascontiguousarray(np.asarray(cost, dtype=np.float64) / spp)
    t = np.empty(per_sample.shape)
    _log_scale(per_sample.reshape(-1), t.reshape(-1))
    t = np.clip(t, 0.0, 1.0) * (len(RAMP) - 1)
    i = np.minimum(t.astype(np.int64), len(RAMP) - 2)
    f = (t - i)[..., None]
    return ((1.0 - f) * RAMP[i] + f * RAMP[i + 1]).astype(np.float32)

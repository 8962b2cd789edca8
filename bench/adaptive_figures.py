"""The figures of ``bench/adaptive.py``: per scene, an adaptive frame where it reaches the
target beside its samples-per-pixel map, and where the uniform frame's error was then.

A *snapshot* (what ``adaptive.frame_run`` keeps of the first wave at or below its target) is a
dict: ``image`` (H, W, 3), ``pixel_spp`` (H, W), ``terms`` (H, W: each pixel's relative
squared error against the reference, the mean over its channels), ``rel_mse`` and
``mean_spp``.
"""

from pathlib import Path

import numpy as np


def spp_map_figure(
    name: str, target: float, adaptive: dict, uniform: dict | None, path: Path
) -> Path:
    """Write ``path`` (PNG): the adaptive frame at ``target``, its samples per pixel (colour
    bar), and the uniform frame's per-pixel relative squared error at its own target wave
    (log colour bar) when ``uniform`` is given."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import LogNorm

    from tracer.accuracy.error_estimate import to_display  # after common.py set the path

    panels = 3 if uniform is not None else 2
    height, width = adaptive["pixel_spp"].shape
    fig, axes = plt.subplots(1, panels, figsize=(3.6 * panels, 3.2 * height / width + 0.9))
    axes[0].imshow(to_display(adaptive["image"]), interpolation="nearest")
    axes[0].set_title(f"adaptive: relMSE {adaptive['rel_mse']:.2g}", fontsize=8)
    spp = adaptive["pixel_spp"]
    shown = axes[1].imshow(spp, cmap="viridis", interpolation="nearest")
    fig.colorbar(shown, ax=axes[1], fraction=0.046, pad=0.04, label="samples per pixel")
    axes[1].set_title(f"its samples per pixel: mean {spp.mean():.0f}, "
                      f"{spp.min()} to {spp.max()}", fontsize=8)  # fmt: skip
    if uniform is not None:
        terms = np.maximum(uniform["terms"], 1e-6)
        shown = axes[2].imshow(terms, cmap="magma", norm=LogNorm(), interpolation="nearest")
        fig.colorbar(shown, ax=axes[2], fraction=0.046, pad=0.04, label="relative squared error")
        axes[2].set_title(f"uniform at {uniform['mean_spp']:.0f} spp: error per pixel",
                          fontsize=8)  # fmt: skip
    for ax in axes:
        ax.axis("off")
    fig.suptitle(f"{name} ({width}x{height}): the first wave at relative MSE <= {target:g}",
                 fontsize=9)  # fmt: skip
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path

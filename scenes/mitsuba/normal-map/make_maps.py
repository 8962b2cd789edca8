"""Write the normal maps of this cross-check scene (run from anywhere; deterministic):
``bumps.png``, a grid of round bumps (tilts up to about 19 degrees), and ``ridges.png``, ridges
along ``u`` (tilts toward +-v up to about 20 degrees), both 8-bit, encoded as ``(n + 1) / 2``."""

from pathlib import Path

import numpy as np
from PIL import Image

HERE = Path(__file__).resolve().parent


def encoded(slope_x: np.ndarray, slope_y: np.ndarray) -> Image.Image:
    n = np.stack([slope_x, slope_y, np.ones_like(slope_x)], axis=-1)
    n /= np.sqrt((n * n).sum(axis=-1, keepdims=True))
    return Image.fromarray(np.rint((n + 1.0) * 127.5).astype(np.uint8))


def main() -> None:
    y, x = (np.mgrid[0:64, 0:64] + 0.5) / 64.0
    # Bumps: the gradient of a height field of four by four cosine domes.
    phase_x, phase_y = 2 * np.pi * 4 * x, 2 * np.pi * 4 * y
    encoded(0.25 * np.sin(phase_x) * np.cos(phase_y),
            -0.25 * np.cos(phase_x) * np.sin(phase_y)).save(HERE / "bumps.png")  # fmt: skip
    # Ridges: the height varies along v only; image rows run from the top (v = 1) down.
    encoded(np.zeros_like(x), 0.36 * np.sin(2 * np.pi * 6 * (1.0 - y))).save(HERE / "ridges.png")


if __name__ == "__main__":
    main()

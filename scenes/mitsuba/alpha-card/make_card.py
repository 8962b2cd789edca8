"""Write the card image of this cross-check scene (deterministic).

``card.png`` is 16 x 16 RGBA: its colour red growing to the right and green growing upward (a
flipped ``u`` or ``v`` shows), its alpha a checker of 4 x 4-texel blocks, the top-left block
opaque, the others alternating between opaque (255) and transparent (0). A mask at cutoff 0.5
cuts it along texel edges. Licence: the project's own.

    python scenes/mitsuba/alpha-card/make_card.py
"""

from pathlib import Path

import numpy as np
from PIL import Image

HERE = Path(__file__).parent


def card() -> np.ndarray:
    y, x = np.mgrid[0:16, 0:16]
    image = np.empty((16, 16, 4), np.uint8)
    image[..., 0] = 60 + 12 * x
    image[..., 1] = 60 + 12 * (15 - y)
    image[..., 2] = 90
    image[..., 3] = np.where((x // 4 + y // 4) % 2 == 0, 255, 0)
    return image


if __name__ == "__main__":
    Image.fromarray(card(), "RGBA").save(HERE / "card.png")

"""Write the textures and the OBJ/MTL sign of this cross-check scene (deterministic).

Every image is asymmetric in both directions, so that a texture read upside down or mirrored
shows: ``tiles.png`` (8 x 8: a checker with a red top row and a blue left column),
``poster.png`` (24 x 16: red growing to the right, green growing upward, a white diagonal
from the bottom left) and ``quadrants.png`` (16 x 16: red, green, blue and yellow quarters,
the red one at the top left). ``sign.obj`` is a 1.2 x 0.9 quad whose UVs span the image twice
across (``vt`` 0..2, repeated), with ``sign.mtl`` tinting ``quadrants.png``. Licence: the
project's own.

    python scenes/mitsuba/textured/make_images.py
"""

from pathlib import Path

import numpy as np
from PIL import Image

HERE = Path(__file__).parent


def tiles() -> np.ndarray:
    y, x = np.mgrid[0:8, 0:8]
    image = np.where(((x + y) % 2 == 0)[..., None], [225, 215, 190], [70, 80, 95])
    image[0] = [200, 40, 30]  # the top row
    image[1:, 0] = [40, 70, 200]  # the left column below it
    return image.astype(np.uint8)


def poster() -> np.ndarray:
    y, x = np.mgrid[0:16, 0:24]
    image = np.stack([40 + 9 * x, 30 + 14 * (15 - y), np.full_like(x, 60)], axis=-1)
    diagonal = np.abs((15 - y) - x * 15 / 23) < 0.8
    image[diagonal] = [250, 250, 250]
    return np.clip(image, 0, 255).astype(np.uint8)


def quadrants() -> np.ndarray:
    image = np.zeros((16, 16, 3), np.uint8)
    image[:8, :8] = [220, 40, 40]
    image[:8, 8:] = [40, 200, 60]
    image[8:, :8] = [40, 60, 220]
    image[8:, 8:] = [230, 210, 40]
    return image


SIGN_OBJ = """# A 1.2 x 0.9 sign in the xy plane facing +z, its image twice across (make_images.py)
mtllib sign.mtl
v -0.6 -0.45 0
v 0.6 -0.45 0
v 0.6 0.45 0
v -0.6 0.45 0
vt 0 0
vt 2 0
vt 2 1
vt 0 1
usemtl sign
f 1/1 2/2 3/3
f 1/1 3/3 4/4
"""
SIGN_MTL = """newmtl sign
Kd 0.9 0.85 0.8
map_Kd quadrants.png
"""


def main() -> None:
    for name, image in (("tiles", tiles()), ("poster", poster()), ("quadrants", quadrants())):
        Image.fromarray(image, mode="RGB").save(HERE / f"{name}.png")
    (HERE / "sign.obj").write_text(SIGN_OBJ)
    (HERE / "sign.mtl").write_text(SIGN_MTL)


if __name__ == "__main__":
    main()

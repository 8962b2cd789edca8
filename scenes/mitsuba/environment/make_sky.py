"""Write ``sky.exr``: the coarse environment map of this cross-check scene.

64 x 32 pixels (5.6 degrees each): coarse, so that the map's pixels show and a map turned or
mirrored the wrong way changes the image. A sky whose colour turns with the azimuth (warm
toward map +x, cool toward -x), a 2 x 2-pixel "sun" of radiance 40 (elevation 28-39 degrees,
azimuth -68 to -56 degrees in the map), and a ground that continues the horizon's colour and
darkens toward the nadir. Directly seen parts change by at most a few percent from one pixel
to the next: the export's bilinear bitmap departs from our nearest-pixel lookup by a fraction
of the step between neighbouring pixels (docs/mitsuba.md). Equirectangular with the convention
of docs/scene-format.md (top row +y, image centre -z); float32, deterministic. Licence: the
project's own.

    python scenes/mitsuba/environment/make_sky.py
"""

from pathlib import Path

import numpy as np
import OpenEXR

WIDTH, HEIGHT = 64, 32
ZENITH = np.array([0.12, 0.25, 0.60])
HORIZON = np.array([0.60, 0.66, 0.75])
WARM = np.array([0.35, 0.12, -0.10])
"""Added to the sky toward azimuth 90 degrees (map +x), subtracted on the opposite side."""
SUN = np.array([40.0, 36.0, 30.0])
SUN_PIXELS = (slice(9, 11), slice(20, 22))
"""Rows 9-10 (polar angle 51-62 degrees) and columns 20-21 (azimuth -68 to -56 degrees)."""
GROUND_FALL = 0.6
"""Below the horizon the radiance is the horizon's times ``1 + GROUND_FALL * y`` (y < 0)."""


def sky_image() -> np.ndarray:
    """The map's linear RGB radiance, float32 (H, W, 3)."""
    theta = np.pi * (np.arange(HEIGHT) + 0.5) / HEIGHT
    phi = 2.0 * np.pi * ((np.arange(WIDTH) + 0.5) / WIDTH - 0.5)
    t, p = np.meshgrid(theta, phi, indexing="ij")
    y = np.cos(t)[..., None]
    side = np.sin(p)[..., None]  # +1 toward map +x, -1 toward -x
    horizon = HORIZON + WARM * side * 0.8
    sky = horizon + (ZENITH - HORIZON) * np.clip(y, 0.0, 1.0)
    ground = horizon * (1.0 + GROUND_FALL * y)
    image = np.where(y > 0.0, sky, ground)
    image[SUN_PIXELS] = SUN
    return np.clip(image, 0.0, None).astype(np.float32)


def main() -> None:
    image = sky_image()
    path = Path(__file__).with_name("sky.exr")
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    OpenEXR.File(header, {"RGB": image}).write(str(path))
    print(f"{path}: {WIDTH} x {HEIGHT}, peak {image.max():.0f}, mean {image.mean():.3f}")


if __name__ == "__main__":
    main()

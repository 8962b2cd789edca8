"""Write ``sky.exr``: the procedural HDR environment map of this sample scene.

A clear sky (blue at the zenith, pale at the horizon, a glow around the sun), a ground
below the horizon, and a small, very bright sun: 1.5 degrees in radius, giving about three times
the sky's irradiance from about 0.02% of the sphere, the case importance sampling is for.
Equirectangular with the convention of docs/scene-format.md (top row +y, image centre -z).
Half floats, ZIP-compressed; deterministic. Licence: the project's own.

    python scenes/environment/make_sky.py
"""

from pathlib import Path

import numpy as np
import OpenEXR

WIDTH, HEIGHT = 512, 256
TO_SUN = np.array([-0.5, 0.62, 0.6])
SUN_RADIUS_DEG = 1.5
SUN_IRRADIANCE = np.array([4.2, 3.9, 3.4])
"""Irradiance on a surface facing the sun (W m^-2); the disc's radiance follows from it."""
ZENITH = np.array([0.10, 0.22, 0.55])
HORIZON = np.array([0.62, 0.68, 0.78])
GROUND = np.array([0.42, 0.39, 0.34])
"""About the radiance of the lit ground plane, so the map's ground continues it at the horizon."""


def directions(width: int, height: int) -> np.ndarray:
    """Unit direction of each pixel centre, (H, W, 3)."""
    theta = np.pi * (np.arange(height) + 0.5) / height
    phi = 2.0 * np.pi * ((np.arange(width) + 0.5) / width - 0.5)
    t, p = np.meshgrid(theta, phi, indexing="ij")
    return np.stack([np.sin(t) * np.sin(p), np.cos(t), -np.sin(t) * np.cos(p)], axis=-1)


def sky_image(width: int = WIDTH, height: int = HEIGHT) -> np.ndarray:
    """The map's linear RGB radiance, float32 (H, W, 3)."""
    d = directions(width, height)
    to_sun = TO_SUN / np.linalg.norm(TO_SUN)
    y = d[..., 1:2]
    up = np.sqrt(np.clip(y, 0.0, 1.0))
    sky = HORIZON + (ZENITH - HORIZON) * up
    cos_sun = d @ to_sun
    glow = 0.6 * np.exp((cos_sun[..., None] - 1.0) / 0.02) * (y > 0.0)
    image = np.where(y > 0.0, sky + glow * np.array([1.0, 0.85, 0.6]), GROUND)
    radius = np.radians(SUN_RADIUS_DEG)
    disc = cos_sun > np.cos(radius)
    # The disc's pixels cover a solid angle close to the cone's; scale its radiance so the
    # pixels deliver the irradiance asked for.
    pixel_solid_angle = (2.0 * np.pi / width) * (np.pi / height) * np.sin(np.arccos(d[..., 1]))
    covered = pixel_solid_angle[disc].sum()
    image[disc] = SUN_IRRADIANCE / covered
    return image.astype(np.float32)


def main() -> None:
    image = sky_image()
    path = Path(__file__).with_name("sky.exr")
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    OpenEXR.File(header, {"RGB": image.astype(np.float16)}).write(str(path))
    print(f"{path}: {WIDTH} x {HEIGHT}, peak {image.max():.0f}, mean {image.mean():.3f}")


if __name__ == "__main__":
    main()

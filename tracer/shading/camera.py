"""Pinhole and thin-lens cameras: a float64 array of 16 values that kernels read, and their
primary rays.

The thin lens (pbrt-v4's ``PerspectiveCamera``) keeps the pinhole's image of the focus plane:
a pinhole ray through the film position meets the plane at distance ``focus_distance`` along the
view direction; the thin-lens ray starts at a point on the lens disc (radius
``aperture_radius``, in the plane of the film's right and up vectors) and goes through that
point. An aperture of 0 is the pinhole, ray for ray.
"""

import math

import numpy as np

from tracer.kernel.jit import jit, jit_inline
from tracer.maths import portable
from tracer.maths.rng import uniform2
from tracer.shading.sampling import square_to_uniform_disk_concentric

LENS_RADIUS = 14
FOCUS_DISTANCE = 15
LENS_DIM = 8
"""Random dimension of a camera sample's lens point (two uniforms; dimension 0 jitters the
pixel). In the path tracer's layout (``tracer.integrators.path``) it is the last spare dimension of
the first vertex."""


def camera_array(
    position,
    look_at,
    up,
    vfov_deg: float,
    width: int,
    height: int,
    aperture_radius: float = 0.0,
    focus_distance: float | None = None,
) -> np.ndarray:
    """Camera constants for kernels, float64 (16,): position (3), forward (3), right (3), up (3),
    tan(vfov / 2), aspect (width / height), lens radius, focus distance; raises ValueError for a
    degenerate frame. The focus distance defaults to the distance from ``position`` to
    ``look_at``."""
    position = np.asarray(position, dtype=np.float64)
    forward = np.asarray(look_at, dtype=np.float64) - position
    norm = portable.norm(forward)
    if not norm > 0.0:
        raise ValueError("camera look_at must differ from its position")
    norm_forward = float(norm)
    forward /= norm
    right = portable.cross(forward, np.asarray(up, dtype=np.float64))
    norm = portable.norm(right)
    if not norm > 1e-12:
        raise ValueError("camera up must not be parallel to the viewing direction")
    right /= norm
    true_up = portable.cross(right, forward)
    tan_half = math.tan(math.radians(vfov_deg) * 0.5)
    if focus_distance is None:
        focus_distance = norm_forward
    lens = [float(aperture_radius), float(focus_distance)]
    return np.concatenate([position, forward, right, true_up, [tan_half, width / height], lens])


@jit
def primary_ray(camera, width, height, fx, fy):
    """Unit direction through film position (fx, fy) in pixels; (0, 0) is the top-left corner."""
    sx = (2.0 * fx / width - 1.0) * camera[12] * camera[13]
    sy = (1.0 - 2.0 * fy / height) * camera[12]
    dx = camera[3] + sx * camera[6] + sy * camera[9]
    dy = camera[4] + sx * camera[7] + sy * camera[10]
    dz = camera[5] + sx * camera[8] + sy * camera[11]
    inv = 1.0 / math.sqrt(dx * dx + dy * dy + dz * dz)
    return (camera[0], camera[1], camera[2]), (dx * inv, dy * inv, dz * inv)


@jit
def thin_lens_ray(camera, width, height, fx, fy, u1, u2):
    """Ray through film position (fx, fy) from the lens point that ``(u1, u2)`` picks (the
    concentric disc map); rays of one film position meet on the focus plane."""
    o, d = primary_ray(camera, width, height, fx, fy)
    radius = camera[LENS_RADIUS]
    if radius <= 0.0:
        return o, d
    # Where the pinhole ray meets the plane of focus (perpendicular to the view direction).
    t = camera[FOCUS_DISTANCE] / (d[0] * camera[3] + d[1] * camera[4] + d[2] * camera[5])
    fx_ = o[0] + t * d[0]
    fy_ = o[1] + t * d[1]
    fz_ = o[2] + t * d[2]
    lx, ly = square_to_uniform_disk_concentric(u1, u2)
    lx *= radius
    ly *= radius
    ox = o[0] + lx * camera[6] + ly * camera[9]
    oy = o[1] + lx * camera[7] + ly * camera[10]
    oz = o[2] + lx * camera[8] + ly * camera[11]
    dx = fx_ - ox
    dy = fy_ - oy
    dz = fz_ - oz
    inv = 1.0 / math.sqrt(dx * dx + dy * dy + dz * dz)
    return (ox, oy, oz), (dx * inv, dy * inv, dz * inv)


@jit_inline
def camera_sample_ray(camera, width, height, x, y, key):
    """The primary ray of one camera sample of pixel (x, y): the film position jittered by
    dimension 0 of ``key``, the lens point (when the camera has an aperture) by ``LENS_DIM``."""
    jx, jy = uniform2(key, 0)
    if camera[LENS_RADIUS] > 0.0:
        l1, l2 = uniform2(key, LENS_DIM)
        return thin_lens_ray(camera, width, height, x + jx, y + jy, l1, l2)
    return primary_ray(camera, width, height, x + jx, y + jy)

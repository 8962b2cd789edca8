"""Pinhole camera: a float64 array of 14 values that kernels read, and its primary rays."""

import math

import numpy as np

from tracer.jit import jit

CAMERA_SIZE = 14
"""Layout: position (3), forward (3), right (3), up (3), tan(vfov / 2), aspect (width / height)."""


def camera_array(position, look_at, up, vfov_deg: float, width: int, height: int) -> np.ndarray:
    """Camera constants for kernels; raises ValueError for a degenerate frame."""
    position = np.asarray(position, dtype=np.float64)
    forward = np.asarray(look_at, dtype=np.float64) - position
    norm = np.linalg.norm(forward)
    if not norm > 0.0:
        raise ValueError("camera look_at must differ from its position")
    forward /= norm
    right = np.cross(forward, np.asarray(up, dtype=np.float64))
    norm = np.linalg.norm(right)
    if not norm > 1e-12:
        raise ValueError("camera up must not be parallel to the viewing direction")
    right /= norm
    true_up = np.cross(right, forward)
    tan_half = math.tan(math.radians(vfov_deg) * 0.5)
    return np.concatenate([position, forward, right, true_up, [tan_half, width / height]])


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

"""Environment-map skies as scene data: the image file read and checked, and the
:class:`EnvironmentMap` a scene state holds (the file's description together with its pixels).

A scene file names the image (``fmt.EnvironmentSky``); the loader reads it once, so states,
snapshots and replicas carry the pixels themselves, as they carry meshes. Accepted files:
OpenEXR (``.exr``; its R, G and B channels, any other channel ignored) and NumPy (``.npy``; a
float array (H, W, 3)), linear RGB radiance, row 0 at the top. Every problem raises
:class:`SceneError` naming the file.
"""

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tracer import config
from tracer.errors import SceneError
from tracer.maths import portable
from tracer.scene import format as fmt


@dataclass(frozen=True, eq=False)
class EnvironmentMap:
    """An environment sky with its image: ``model`` as the scene file gives it, ``image`` the
    read-only float32 (H, W, 3) radiance before ``model.scale``. Build with
    :func:`environment_map`, which checks the image."""

    model: fmt.EnvironmentSky
    image: np.ndarray

    @property
    def type(self) -> str:
        return self.model.type

    def mean_radiance(self) -> tuple[float, float, float]:
        """Radiance averaged over the sphere (solid-angle weighted), scale included."""
        h = self.image.shape[0]
        edges = portable.elementwise(math.cos, np.pi * np.arange(h + 1) / h)
        row_weight = (edges[:-1] - edges[1:]) / 2.0  # solid angle of each row / 4 pi
        per_row = self.image.astype(np.float64).mean(axis=1)
        mean = (row_weight[:, None] * per_row).sum(axis=0) * self.model.scale
        return tuple(float(c) for c in mean)


def check_image(image: np.ndarray, label: str) -> np.ndarray:
    """``image`` as a read-only float32 (H, W, 3) array of finite non-negative radiance, or
    SceneError naming ``label``."""
    image = np.asarray(image)
    if image.ndim != 3 or image.shape[2] != 3 or image.shape[0] < 1 or image.shape[1] < 1:
        raise SceneError(
            f"{label}: an environment map must be an (H, W, 3) image, not shape {image.shape}"
        )
    _check_size(image.shape[0], image.shape[1], label)
    if not np.issubdtype(image.dtype, np.floating):
        raise SceneError(f"{label}: an environment map holds floats, not {image.dtype}")
    with np.errstate(over="ignore"):
        pixels = np.array(image, dtype=np.float32)
    finite = np.isfinite(pixels)
    if not finite.all():
        y, x, _ = np.argwhere(~finite)[0]
        raise SceneError(f"{label}: pixel (row {y}, column {x}) is NaN or infinite in float32")
    if (pixels < 0.0).any():
        y, x, _ = np.argwhere(pixels < 0.0)[0]
        raise SceneError(f"{label}: pixel (row {y}, column {x}) has negative radiance")
    pixels.setflags(write=False)
    return pixels


def _check_size(height: int, width: int, label: str) -> None:
    if max(height, width) > config.MAX_IMAGE_SIDE or height * width > config.MAX_ENVIRONMENT_PIXELS:
        raise SceneError(
            f"{label}: a {width} x {height} environment map is too large (at most "
            f"{config.MAX_IMAGE_SIDE} pixels a side and {config.MAX_ENVIRONMENT_PIXELS} in all)"
        )


def environment_map(model: fmt.EnvironmentSky, image: np.ndarray) -> EnvironmentMap:
    """A checked :class:`EnvironmentMap` of ``model`` and its pixels."""
    return EnvironmentMap(model, check_image(image, model.file))


def read_environment_image(path: Path, label: str) -> np.ndarray:
    """The pixels of an environment image file (see the module docstring), checked."""
    suffix = path.suffix.lower()
    if suffix == ".npy":
        image = _read_npy(path, label)
    elif suffix == ".exr":
        image = _read_exr(path, label)
    else:
        raise SceneError(
            f"{label}: unknown environment map type {suffix or '(none)'!r} (use .exr or .npy)"
        )
    return check_image(image, label)


def _read_npy(path: Path, label: str) -> np.ndarray:
    try:
        image = np.load(path, mmap_mode="r", allow_pickle=False)
    except (ValueError, OSError, EOFError) as exc:
        raise SceneError(f"{label}: not a NumPy array file ({exc})") from None
    if image.ndim == 3 and image.shape[2] == 3:
        _check_size(image.shape[0], image.shape[1], label)
    return image


def _read_exr(path: Path, label: str) -> np.ndarray:
    import OpenEXR

    try:
        with OpenEXR.File(str(path), header_only=True) as f:
            lo, hi = f.header()["dataWindow"]
        _check_size(int(hi[1] - lo[1] + 1), int(hi[0] - lo[0] + 1), label)
        with OpenEXR.File(str(path), separate_channels=True) as f:
            channels = {name: c.pixels for name, c in f.channels().items()}
    except RuntimeError as exc:
        raise SceneError(f"{label}: cannot read OpenEXR file ({exc})") from None
    missing = [c for c in "RGB" if c not in channels]
    if missing:
        raise SceneError(
            f"{label}: the OpenEXR file has no {', '.join(missing)} channel "
            f"(it has {', '.join(sorted(channels)) or 'none'})"
        )
    shapes = {channels[c].shape for c in "RGB"}
    if len(shapes) != 1:
        raise SceneError(f"{label}: the R, G and B channels differ in size (subsampled?)")
    return np.stack([channels[c] for c in "RGB"], axis=-1)

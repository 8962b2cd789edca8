"""Denoising a frame with Intel Open Image Denoise (OIDN 2.5, through the ``pyoidn`` binding).

:func:`denoise` runs OIDN's ``RT`` filter on the CPU over a linear HDR beauty image, optionally
guided by an albedo and a normal image. Noisy guides (a path tracer's first-hit albedo and
normal at low spp) are prefiltered as OIDN's documentation recommends: each guide is denoised
by its own ``RT`` filter first, and the beauty is then denoised with ``cleanAux``. One
committed OIDN device per thread count is kept for the life of the process and shared by every
call (creating one is slow), with its filters (``tracer.post.oidn_filters``), each behind its own
lock, so concurrent calls are serialised per device. OIDN's output is deterministic on one
machine, but may differ slightly between CPUs with different instruction sets (AVX2, AVX-512,
AMX), since each runs its own kernels. Figures and the reading of the qualities and guides:
``docs/denoising.md``.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from types import ModuleType

import numpy as np

from tracer.errors import TilerenderError
from tracer.kernel.threads import default_threads
from tracer.post.oidn_filters import FilterCache

QUALITIES = ("fast", "balanced", "high")
"""``quality``'s choices, OIDN's ``OIDN_QUALITY_FAST``, ``_BALANCED`` and ``_HIGH``."""

GUIDES = ("albedo", "normal")
"""The guides ``denoise`` takes, and may prefilter."""

_OIDN_QUALITY = {"fast": 4, "balanced": 5, "high": 6}  # the values of OIDNQuality (oidn.h)

PREFILTER_QUALITY = {"fast": "fast", "balanced": "balanced", "high": "balanced"}
"""The quality the guides are prefiltered at, for each quality of the beauty: at most
``balanced``, which measured about the error of ``high`` prefilters in much less time
(``docs/denoising.md``, Guides and prefiltering)."""

_INSTALL_HINT = "install the locked dependencies (./dev shell true) or pip install 'pyoidn>=2.5'"


class DenoiserUnavailable(TilerenderError, RuntimeError):
    """pyoidn cannot be imported, or OIDN cannot create a CPU device on this machine."""


class DenoiseFailed(TilerenderError, RuntimeError):
    """OIDN reported an error while configuring or running a filter."""


@dataclass(frozen=True)
class Denoised:
    """A denoised frame and what was done to make it."""

    image: np.ndarray  # float32 (H, W, 3)
    seconds: float  # the whole call, validation and prefiltering included
    quality: str  # one of QUALITIES
    guides: tuple[str, ...]  # (), ("albedo",) or ("albedo", "normal")
    prefiltered: bool  # guides were denoised first and the beauty with cleanAux
    prefiltered_guides: tuple[str, ...] = ()  # which guides were denoised first


@dataclass
class _Device:
    device: object  # pyoidn.Device, committed
    lock: threading.Lock  # held for every use of the device and its filters
    filters: FilterCache


_devices: dict[int, _Device] = {}
"""Committed OIDN CPU devices of this process, by thread count."""
_devices_lock = threading.Lock()


def _load_pyoidn() -> ModuleType:
    try:
        import pyoidn
    except (ImportError, OSError) as error:  # OSError: the bundled library does not load
        raise DenoiserUnavailable(
            f"the denoiser needs pyoidn, which cannot be imported ({error}): {_INSTALL_HINT}"
        ) from error
    return pyoidn


def require_denoiser() -> None:
    """Raise ``DenoiserUnavailable`` now if pyoidn cannot be imported (a front door checks
    before it renders a frame it would then fail to denoise)."""
    _load_pyoidn()


def _device(pyoidn: ModuleType, threads: int) -> _Device:
    """The process's committed CPU device with ``threads`` threads, created on first use."""
    with _devices_lock:
        entry = _devices.get(threads)
        if entry is not None:
            return entry
        if not pyoidn.Device.is_cpu_available():
            raise DenoiserUnavailable("OIDN does not support this CPU (it needs at least SSE4.1)")
        device = pyoidn.Device(pyoidn.OIDN_DEVICE_TYPE_CPU)
        error = device.get_error()
        if error is None:
            device.set_int("numThreads", threads)
            device.commit()
            error = device.get_error()
        if error is not None:
            raise DenoiserUnavailable(f"OIDN could not create a CPU device: {error}")
        entry = _devices[threads] = _Device(device, threading.Lock(), FilterCache(pyoidn, device))
        return entry


def _check_image(name: str, array: object, shape: tuple[int, ...] | None) -> np.ndarray:
    """``array`` as a new C-contiguous float32 (H, W, 3) array, or ValueError naming ``name``."""
    if not isinstance(array, np.ndarray):
        raise ValueError(f"{name} must be a numpy array, not {type(array).__name__}")
    if not np.issubdtype(array.dtype, np.floating):
        raise ValueError(f"{name} must be a float array, not {array.dtype}")
    if array.ndim != 3 or array.shape[2] != 3 or array.shape[0] == 0 or array.shape[1] == 0:
        raise ValueError(f"{name} must have shape (H, W, 3) with H, W >= 1, not {array.shape}")
    if shape is not None and array.shape != shape:
        raise ValueError(f"{name} has shape {array.shape}, the beauty {shape}: they must be equal")
    image = np.array(array, dtype=np.float32, order="C", copy=True)
    if not np.isfinite(image).all():
        raise ValueError(f"{name} has values that are not finite (NaN or inf as float32)")
    return image


def _run_filter(entry: _Device, images: dict, options: dict) -> None:
    """Run an ``RT`` filter of ``entry``'s over ``images`` (name -> float32 array) with
    ``options``, or raise DenoiseFailed."""
    error = entry.filters.run(images, options)
    if error is not None:
        raise DenoiseFailed(f"OIDN failed to denoise ({', '.join(images)}): {error}")


def denoise(
    beauty: np.ndarray,
    albedo: np.ndarray | None = None,
    normal: np.ndarray | None = None,
    quality: str = "high",
    threads: int | None = None,
    prefilter: bool | tuple[str, ...] = True,
    prefilter_quality: str | None = None,
) -> Denoised:
    """Denoise a linear HDR ``beauty`` (H, W, 3) with OIDN's ``RT`` filter on the CPU.

    ``albedo`` (clamped to [0, 1]) and ``normal`` (world space, in [-1, 1]) are optional guides
    of the same shape; a normal needs an albedo. With ``prefilter`` True the guides are denoised
    first (at ``prefilter_quality``, default ``PREFILTER_QUALITY[quality]``) and the beauty
    with ``cleanAux``; a tuple of guide names (``GUIDES``) prefilters only those of them given,
    the others counted clean as they are; with False OIDN takes the guides as they are, noisy
    (right for noise-free guides, and cheapest). ``threads`` defaults to the CPUs this
    process may use. The caller's arrays are never modified. Raises ValueError for bad input,
    DenoiserUnavailable when pyoidn or OIDN's CPU device is missing, DenoiseFailed when OIDN
    reports an error.
    """
    start = time.perf_counter()
    if quality not in QUALITIES:
        raise ValueError(f"quality must be one of {', '.join(QUALITIES)}, not {quality!r}")
    prefilter_quality = prefilter_quality or PREFILTER_QUALITY[quality]
    if prefilter_quality not in QUALITIES:
        raise ValueError(
            f"prefilter_quality must be one of {', '.join(QUALITIES)}, not {prefilter_quality!r}"
        )
    if not isinstance(prefilter, bool) and (
        not isinstance(prefilter, tuple) or not set(prefilter) <= set(GUIDES)
    ):
        raise ValueError(f"prefilter must be a bool or a tuple of {GUIDES}, not {prefilter!r}")
    if threads is not None and (
        isinstance(threads, bool) or not isinstance(threads, int) or threads < 1
    ):
        raise ValueError(f"threads must be a whole number >= 1 or None, not {threads!r}")
    if normal is not None and albedo is None:
        raise ValueError("normal needs albedo: OIDN takes a normal guide only with an albedo")
    color = _check_image("beauty", beauty, None)
    if (color < 0).any():
        raise ValueError("beauty has negative values: OIDN's HDR input must be >= 0")
    guides: dict[str, np.ndarray] = {}
    if albedo is not None:
        guides["albedo"] = np.clip(_check_image("albedo", albedo, color.shape), 0.0, 1.0)
    if normal is not None:
        guides["normal"] = _check_image("normal", normal, color.shape)

    pyoidn = _load_pyoidn()
    entry = _device(pyoidn, threads or default_threads())
    level = _OIDN_QUALITY[quality]
    guide_level = _OIDN_QUALITY[prefilter_quality]
    output = np.empty_like(color)
    chosen = GUIDES if prefilter is True else prefilter or ()
    prefiltered = tuple(name for name in guides if name in chosen)
    with entry.lock:
        for name in prefiltered:  # in place: the guides are this call's copies
            guide = guides[name]
            _run_filter(entry, {name: guide, "output": guide}, {"quality": guide_level})
        images = {"color": color, **guides, "output": output}
        options = {"hdr": True, "cleanAux": bool(prefiltered), "quality": level}
        _run_filter(entry, images, options)
    return Denoised(
        image=output,
        seconds=time.perf_counter() - start,
        quality=quality,
        guides=tuple(guides),
        prefiltered=bool(prefiltered),
        prefiltered_guides=prefiltered,
    )

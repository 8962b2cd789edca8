"""A finished frame's layers: the beauty, its AOVs by name and, when the settings ask for it, the
denoised beauty, made once from the assembled frame (never per tracer range: seams)."""

import numpy as np

from tracer.integrators.aov import LAYERS, aov_layers
from tracer.post.denoise import Denoised, DenoiseFailed, denoise
from tracer.post.guides import prefilter_argument
from tracer.scene import format as fmt


def rendered_layers(settings: fmt.RenderSettings) -> tuple[str, ...]:
    """The layers a render with ``settings`` has, in file order."""
    names = ["beauty"]
    if settings.denoise != "off":
        names.append("denoised")
    if settings.aovs:
        names += list(LAYERS)
    return tuple(names)


def frame_layers(
    rgb: np.ndarray,
    aov: np.ndarray | None,
    settings: fmt.RenderSettings,
    threads: int | None = None,
) -> tuple[dict[str, np.ndarray], dict]:
    """The layers of an assembled frame (``rgb`` (H, W, 3), ``aov`` (H, W, ``aov.CHANNELS``)
    or None) and what making them took, for the image's metadata.

    The AOV layers are kept when ``settings.aovs`` asks for them; else they only guide the
    denoiser. When ``settings.denoise`` asks for the denoised layer, the albedo and normal
    guide it where the frame has them, prefiltered as ``settings.denoise_prefilter`` says
    (``tracer.post.guides.prefilter_argument``; ``auto`` left unresolved counts as ``on``), and
    the metadata is ``{"denoise": {...}}`` (its quality, guides, prefiltering and seconds); else
    ``{}``."""
    layers = {"beauty": rgb}
    aovs = aov_layers(aov) if aov is not None else {}
    if settings.denoise == "off":
        return {**layers, **aovs}, {}
    prefilter = prefilter_argument(settings.denoise_prefilter)
    try:
        done = denoise_with_aov(rgb, aov, settings.denoise, prefilter, threads)
    except ValueError as exc:  # a frame OIDN cannot take (the renderer's bug, not the user's)
        raise DenoiseFailed(f"the frame cannot be denoised: {exc}") from None
    layers["denoised"] = done.image
    if settings.aovs:  # else they were the denoiser's guides only
        layers.update(aovs)
    info = {
        "quality": done.quality,
        "guides": list(done.guides),
        "prefiltered": done.prefiltered,
        "prefiltered_guides": list(done.prefiltered_guides),
        "seconds": round(done.seconds, 4),
    }
    return layers, {"denoise": info}


def denoise_with_aov(
    rgb: np.ndarray,
    aov: np.ndarray | None,
    quality: str,
    prefilter: bool | tuple[str, ...],
    threads: int | None = None,
) -> Denoised:
    """``rgb`` (H, W, 3) denoised at ``quality``, guided by the albedo and normal of ``aov``
    (H, W, ``aov.CHANNELS``; None: no guides), those ``prefilter`` names (True: both)
    prefiltered (``tracer.post.denoise.denoise``, whose errors it raises)."""
    albedo = normal = None
    if aov is not None:
        layers = aov_layers(np.asarray(aov, np.float32))
        albedo, normal = layers["albedo"], layers["normal"]
    return denoise(rgb, albedo, normal, quality, threads, prefilter=prefilter)


def default_layer(settings: fmt.RenderSettings) -> str:
    """The layer a single-layer image (PNG, NPY, a plain EXR) shows unless asked for another:
    the denoised beauty when there is one, else the beauty."""
    return "beauty" if settings.denoise == "off" else "denoised"

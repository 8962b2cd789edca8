"""Whether the denoiser's guides need prefiltering: ``render.denoise_prefilter``'s ``auto``,
resolved from the scene a frame shows.

The albedo and normal AOVs (``tracer.integrators.aov``) are means over a pixel's samples. Where
the first non-delta surface a pixel's samples meet varies only across the pixel's footprint, they
are as clean as the pixel filter makes them, and prefiltering them costs more than the beauty's
own denoising and leaves as much error or more; a lens aperture (depth of field) and image
textures make them noisy, and the prefilters then lower the error (``docs/denoising.md``,
Guides and prefiltering). Glass varies them too (each sample reflects or refracts), but on the
glass scene measured the prefilters lowered the error by at most 4% at 4 and 16 spp, for four
times the time, so glass alone does not ask for them."""

from collections.abc import Iterable

from tracer.scene import format as fmt


def guides_are_noisy(materials: Iterable[fmt.Material], camera: fmt.Camera) -> bool:
    """Whether the guides of ``camera``'s view of a scene with ``materials`` carry noise beyond
    the pixel filter's: the camera has a lens aperture, or a material has a texture or a normal
    map."""
    return camera.aperture_radius > 0.0 or any(
        getattr(material, "texture", None) is not None
        or getattr(material, "normal_map", None) is not None
        for material in materials
    )


def resolve_prefilter(
    settings: fmt.RenderSettings, materials: Iterable[fmt.Material], camera: fmt.Camera
) -> fmt.RenderSettings:
    """``settings`` with ``denoise_prefilter`` ``auto`` made ``on`` or ``off`` by
    :func:`guides_are_noisy` (other values kept)."""
    if settings.denoise_prefilter != "auto":
        return settings
    noisy = guides_are_noisy(materials, camera)
    return settings.model_copy(update={"denoise_prefilter": "on" if noisy else "off"})

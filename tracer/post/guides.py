"""Whether the denoiser's guides need prefiltering: ``render.denoise_prefilter``'s ``auto``,
resolved from the scene a frame shows, and what each choice asks of ``tracer.post.denoise``.

The albedo and normal AOVs (``tracer.integrators.aov``) are means over a pixel's samples. Where
the first non-delta surface a pixel's samples meet varies only across the pixel's footprint, they
are as clean as the pixel filter makes them, and prefiltering them costs more than the beauty's
own denoising and leaves as much error or more; a lens aperture (depth of field) and image
textures make them noisy, and the prefilters then lower the error. Textures alone vary the
albedo, not the normal, so the albedo alone is prefiltered there; a lens, a normal map or a
blended surface varies the normal too, so both are. Glass varies them too (each sample
reflects or refracts), but the prefilters gained too little there for their time, so glass
alone does not ask for them. The measurements behind each rule are in ``docs/denoising.md``,
Guides and prefiltering."""

from collections.abc import Iterable

from tracer.scene import format as fmt


def _textured(materials: Iterable[fmt.Material], field: str) -> bool:
    return any(getattr(material, field, None) is not None for material in materials)


def _blended(materials: Iterable[fmt.Material]) -> bool:
    return any(
        getattr(getattr(material, "alpha", None), "mode", None) == "blend" for material in materials
    )


def noisy_guides(materials: Iterable[fmt.Material], camera: fmt.Camera) -> tuple[str, ...]:
    """The guides of ``camera``'s view of a scene with ``materials`` that carry noise beyond the
    pixel filter's: both with a lens aperture, a normal map or a blended (stochastic alpha)
    surface, which each sample meets or passes, the albedo alone with textures only, else
    none."""
    materials = list(materials)
    if camera.aperture_radius > 0.0 or _textured(materials, "normal_map") or _blended(materials):
        return ("albedo", "normal")
    return ("albedo",) if _textured(materials, "texture") else ()


def resolve_prefilter(
    settings: fmt.RenderSettings, materials: Iterable[fmt.Material], camera: fmt.Camera
) -> fmt.RenderSettings:
    """``settings`` with ``denoise_prefilter`` ``auto`` made ``on``, ``albedo`` or ``off`` by
    :func:`noisy_guides` (other values kept)."""
    if settings.denoise_prefilter != "auto":
        return settings
    noisy = noisy_guides(materials, camera)
    choice = {2: "on", 1: "albedo", 0: "off"}[len(noisy)]
    return settings.model_copy(update={"denoise_prefilter": choice})


def prefilter_argument(choice: str) -> bool | tuple[str, ...]:
    """``tracer.post.denoise.denoise``'s ``prefilter`` for a ``denoise_prefilter`` choice:
    ``off`` none, ``albedo`` the albedo, ``on`` (and ``auto`` left unresolved) every guide."""
    return {"off": False, "albedo": ("albedo",)}.get(choice, True)

"""The metadata a rendered image file carries (a PNG text chunk or an EXR header attribute)."""

from importlib.metadata import PackageNotFoundError, version

from tracer.scene import format as fmt


def renderer_version() -> str:
    """The installed tilerender's version ("unknown" when run from a bare source tree)."""
    try:
        return version("tilerender")
    except PackageNotFoundError:
        return "unknown"


def image_metadata(
    camera: fmt.Camera,
    settings: fmt.RenderSettings,
    effect_plan: dict,
    seconds: float,
    rays: int | None,
    executor: str,
    **extra: object,
) -> dict:
    """What rendered an image and how: renderer, camera, settings, effect plan, seconds, rays,
    where it ran (``in-process`` or ``ray``), and ``extra`` fields (frame, tracers, ...)."""
    return {
        "renderer": "tilerender",
        "version": renderer_version(),
        "camera": camera.model_dump(),
        "render": settings.model_dump(),
        "effect_plan": effect_plan,
        "seconds": round(seconds, 3),
        "rays": rays,
        "executor": executor,
        **extra,
    }

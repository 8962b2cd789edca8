"""The metadata a rendered image file carries (a PNG text chunk or an EXR header attribute)."""

from importlib.metadata import PackageNotFoundError, version

from tracer.scene import format as fmt
from tracer.scene.model import SceneState


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


def id_names(state: SceneState, settings: fmt.RenderSettings) -> dict:
    """What the id layers (``tracer.integrators.aov``) of a render with ``settings`` name, for
    its files' metadata: ``{"ids": {"object_id": {id: name}, "material_id": {id: name}}}``, ids
    as JSON's string keys: the scene's objects (nodes with a mesh, by id: a scene file's objects
    by their index, unnamed ones ``objects[i]``) and its materials in their order; ``{}`` when
    the render keeps no AOV layers."""
    if not settings.aovs:
        return {}
    objects = {str(node.id): node.name for node in state.geometry_nodes()}
    materials = {str(i): name for i, name in enumerate(state.materials)}
    return {"ids": {"object_id": objects, "material_id": materials}}

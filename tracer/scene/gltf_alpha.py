"""A glTF material's base-colour alpha: ``alphaMode``, ``alphaCutoff`` and the alpha of
``baseColorFactor`` (times the base colour texture's alpha channel) as the format's
``Alpha`` (docs/materials.md, *Alpha*). ``OPAQUE`` (the default) ignores alpha, as the spec
says."""

from trimesh.visual.material import Material

from tracer.errors import SceneError
from tracer.scene import format as fmt
from tracer.scene.gltf_nodes import finite, numbers

MODES = {"MASK": "mask", "BLEND": "blend"}
DEFAULT_CUTOFF = 0.5


def alpha_mode(spec: dict, material: Material | None, where: str) -> str:
    """``OPAQUE``, ``MASK`` or ``BLEND``: from the material's JSON ``spec`` when found, else as
    trimesh kept it; anything else is a ``SceneError`` at ``where``."""
    mode = spec["alphaMode"] if "alphaMode" in spec else getattr(material, "alphaMode", None)
    mode = "OPAQUE" if mode is None else mode
    if mode not in ("OPAQUE", *MODES):
        raise SceneError(f"{where}: alphaMode {mode!r} is not OPAQUE, MASK or BLEND")
    return mode


def material_alpha(
    spec: dict, material: Material | None, texture: fmt.Texture | None, where: str
) -> fmt.Alpha | None:
    """The ``Alpha`` of a glTF material (None for ``OPAQUE``). ``spec`` is its JSON ({} when it
    cannot be matched: trimesh's values are used), ``material`` trimesh's, ``texture`` its base
    colour texture's alpha channel as a scene image (None when the image has none)."""
    mode = alpha_mode(spec, material, where)
    if mode == "OPAQUE":
        return None
    pbr = spec.get("pbrMetallicRoughness", {})
    if isinstance(pbr, dict) and "baseColorFactor" in pbr:
        value = numbers(pbr["baseColorFactor"], 4, f"{where}.baseColorFactor")[3]
    elif getattr(material, "baseColorFactor", None) is not None:
        value = float(material.baseColorFactor[3]) / 255.0  # trimesh keeps 8 bits
    else:
        value = 1.0
    if not 0.0 <= value <= 1.0:
        raise SceneError(f"{where}: baseColorFactor's alpha {value} is not in [0, 1]")
    cutoff = spec.get("alphaCutoff", getattr(material, "alphaCutoff", None))
    cutoff = DEFAULT_CUTOFF if cutoff is None else cutoff
    if not finite(cutoff) or cutoff < 0.0:
        raise SceneError(f"{where}: alphaCutoff {cutoff!r} is not a number >= 0")
    return fmt.Alpha(mode=MODES[mode], cutoff=float(cutoff), value=value, texture=texture)


def check_alpha(document: dict, file_name: str) -> None:
    """Raise ``SceneError`` on a material of a glTF document whose alpha values are invalid
    (before trimesh reads them: it fails obscurely on some)."""
    materials = document.get("materials", [])
    for i, spec in enumerate(materials if isinstance(materials, list) else []):
        if isinstance(spec, dict):
            name = spec.get("name", i)
            material_alpha(spec, None, None, f"{file_name}: material {name!r}")

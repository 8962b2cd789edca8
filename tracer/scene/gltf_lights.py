"""``KHR_lights_punctual``: a glTF file's point, spot and directional lights as the scene
format's point, spot and sun lights, placed by their nodes (a light shines down its node's -Z).
Photometric units become ours at 683 lm/W (docs/materials.md, "glTF features"). Malformed
lights raise :class:`SceneError`."""

import math

import numpy as np
import pydantic

from tracer.errors import SceneError
from tracer.maths import portable
from tracer.scene import format as fmt
from tracer.scene.gltf_nodes import FileNode, finite, node_extension, scene_nodes

EXTENSION = "KHR_lights_punctual"
LUMENS_PER_WATT = 683.0
"""Candela (lm/sr) per W/sr and lux (lm/m^2) per W/m^2: the luminous efficacy of 555 nm light,
as Blender's glTF importer converts in its default mode."""
DEFAULT_OUTER_CONE = math.pi / 4.0


def file_light_specs(document: dict, label: str) -> list:
    """The file's ``KHR_lights_punctual`` light list (empty without it)."""
    extensions = document.get("extensions", {})
    section = extensions.get(EXTENSION, {}) if isinstance(extensions, dict) else {}
    lights = section.get("lights", []) if isinstance(section, dict) else []
    if not isinstance(lights, list):
        raise SceneError(f"{label}: {EXTENSION}.lights must be a list")
    return lights


def file_lights(document: dict, label: str, placement: np.ndarray | None = None) -> list:
    """The lights of the file's scene as ``fmt.Light`` models in the frame ``placement`` (4x4,
    default identity) puts the file in; lights without power are left out."""
    specs = file_light_specs(document, label)
    placement = np.eye(4) if placement is None else placement
    lights = []
    for node in scene_nodes(document, label):
        reference = node_extension(node, EXTENSION)
        if "light" not in reference:
            continue
        index = reference["light"]
        if isinstance(index, bool) or not isinstance(index, int) or not 0 <= index < len(specs):
            raise SceneError(
                f"{label}: node {node.name!r} uses light {index!r}, which does not exist "
                f"({len(specs)} lights)"
            )
        light = _light(specs[index], node, placement, f"{label}: {EXTENSION} light {index}")
        if light is not None:
            lights.append(light)
    return lights


def _colour(spec: dict, where: str) -> np.ndarray:
    """``color * intensity`` / 683: linear RGB in W/sr (point, spot) or W/m^2 (directional)."""
    colour = spec.get("color", [1.0, 1.0, 1.0])
    intensity = spec.get("intensity", 1.0)
    numbers = colour if isinstance(colour, list) else []
    if len(numbers) != 3 or not all((finite(c) and c >= 0) for c in numbers):
        raise SceneError(f"{where}: color must be 3 finite numbers >= 0")
    if not (finite(intensity) and intensity >= 0):
        raise SceneError(f"{where}: intensity must be a finite number >= 0")
    return np.asarray(numbers, np.float64) * (float(intensity) / LUMENS_PER_WATT)


def _light(spec, node: FileNode, placement: np.ndarray, where: str):
    if not isinstance(spec, dict):
        raise SceneError(f"{where}: not a JSON object")
    kind = spec.get("type")
    if kind not in ("point", "spot", "directional"):
        raise SceneError(f"{where}: unknown type {kind!r} (point, spot or directional)")
    colour = _colour(spec, where)
    if not colour.max() > 0.0:
        return None
    matrix = portable.chain(placement, node.matrix)
    position = tuple(float(c) for c in matrix[:3, 3])
    axis = matrix[:3, 2]
    if not portable.norm(axis) > 0.0:
        raise SceneError(f"{where}: node {node.name!r} scales its z axis to nothing")
    forward = -portable.normalized(axis)
    radiant = tuple(float(c) for c in colour)
    try:
        if kind == "point":
            return fmt.PointLight(type="point", position=position, intensity=radiant)
        if kind == "directional":
            return fmt.SunLight(
                type="sun", to_sun=tuple(-forward), irradiance=radiant, angular_radius_deg=0.0
            )
        cone, falloff = spot_cone(spec.get("spot", {}), where)
        return fmt.SpotLight(
            type="spot",
            position=position,
            look_at=tuple(np.asarray(position) + forward),
            intensity=radiant,
            cone_angle_deg=cone,
            falloff_deg=falloff,
        )
    except pydantic.ValidationError as exc:
        problem = exc.errors()[0]["msg"].removeprefix("Value error, ")
        raise SceneError(f"{where}: {problem}") from None


def spot_cone(spot, where: str) -> tuple[float, float]:
    """``(cone_angle_deg, falloff_deg)`` of a glTF spot: the outer cone, and the band from the
    inner cone to it over which the light fades."""
    if not isinstance(spot, dict):
        raise SceneError(f"{where}: spot must be a JSON object")
    inner = spot.get("innerConeAngle", 0.0)
    outer = spot.get("outerConeAngle", DEFAULT_OUTER_CONE)
    if not (finite(inner) and inner >= 0 and finite(outer) and outer >= 0):
        raise SceneError(f"{where}: spot cone angles must be finite numbers >= 0")
    if not 0.0 < outer <= math.pi / 2.0:
        raise SceneError(f"{where}: outerConeAngle must be in (0, pi/2], not {outer}")
    if inner > outer:
        raise SceneError(f"{where}: innerConeAngle ({inner}) exceeds outerConeAngle ({outer})")
    cone = min(math.degrees(outer), 90.0)
    return cone, min(max(cone - math.degrees(inner), 0.0), cone)

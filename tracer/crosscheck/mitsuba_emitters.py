"""The Mitsuba export's emitters at infinity and delta lights: the sky, an environment map, and
point, spot and sun lights."""

import hashlib
import math
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from tracer.crosscheck.mitsuba_base import (
    UnsupportedFeature,
    child,
    frame,
    look_at,
    rgb,
    scalar,
    to_world,
    triple,
)
from tracer.crosscheck.mitsuba_conversions import (
    SKY_COLUMNS,
    SKY_ROWS,
    SPOT_TEXTURE_SIZE,
    environment_bitmap,
    environment_to_world,
    gradient_sky_bitmap,
    sky_radiance,
    spot_texture,
)
from tracer.io.images import write_image
from tracer.scene import format as fmt
from tracer.scene.environment import EnvironmentMap
from tracer.scene.model import SceneState

SUN_DISTANCE = 1e4
"""A sun with a radius becomes a disc this many scene radii away (parallax below 1e-4 rad)."""


class EmittersWriter:
    """The sky and lights part of the export's writer (``mitsuba_export``): ``write_sky`` and
    ``write_light``."""

    state: SceneState
    out: Path
    center: np.ndarray
    radius: float
    far: float

    def write_sky(self, root: ET.Element) -> None:
        sky = self.state.sky
        if isinstance(sky, EnvironmentMap):
            self._environment(root, sky)
            return
        if isinstance(sky, fmt.ConstantSky):
            if max(sky.radiance) > 0.0:
                emitter = child(root, "emitter", type="constant")
                rgb(emitter, "radiance", sky.radiance)
            return
        if max(max(sky.zenith), max(sky.horizon), max(sky.ground)) <= 0.0:
            return
        write_image(self.out / "textures" / "sky.exr", gradient_sky_bitmap(sky))
        emitter = child(root, "emitter", type="envmap")
        child(emitter, "string", name="filename", value="textures/sky.exr")
        self.note(
            "gradient sky",
            "proxy",
            f"a {SKY_COLUMNS}x{SKY_ROWS} latitude-longitude bitmap, interpolated bilinearly: "
            "within 1e-5 of the gradient except a 0.02-degree band about the horizon",
        )

    def _environment(self, root: ET.Element, sky: EnvironmentMap) -> None:
        if max(sky.mean_radiance()) <= 0.0:
            return  # a black map: no light, as the kernels treat it
        bitmap, factor = environment_bitmap(sky)
        digest = hashlib.sha256(np.ascontiguousarray(bitmap).tobytes()).hexdigest()[:16]
        relative = f"textures/environment-{digest}.exr"
        write_image(self.out / relative, bitmap)
        emitter = child(root, "emitter", type="envmap")
        child(emitter, "string", name="filename", value=relative)
        to_world(emitter, environment_to_world(sky.model.rotation))
        h, w = sky.image.shape[:2]
        self.note(
            "environment map",
            "proxy",
            f"our {w}x{h} map (nearest pixel) upsampled {factor} times to a "
            f"{bitmap.shape[1]}x{bitmap.shape[0]} bitmap that Mitsuba interpolates bilinearly: "
            f"its integral kept, lookups within 1/{factor} of a pixel from the map's pixel "
            "edges differ",
        )

    def write_light(self, root: ET.Element, i: int, light: fmt.Light) -> None:
        if isinstance(light, fmt.PointLight):
            emitter = child(root, "emitter", type="point")
            child(emitter, "point", name="position", value=triple(light.position))
            rgb(emitter, "intensity", light.intensity)
        elif isinstance(light, fmt.SpotLight):
            self._spot(root, i, light)
        elif isinstance(light, fmt.SunLight):
            self._sun(root, i, light)
        else:
            raise UnsupportedFeature(f"lights[{i}] of type {light.type!r}", "no Mitsuba twin")

    def _spot(self, root: ET.Element, i: int, light: fmt.SpotLight) -> None:
        emitter = child(root, "emitter", type="spot")
        rgb(emitter, "intensity", light.intensity)
        # Mitsuba's own falloff is linear in angle; full intensity inside the cone, and ours
        # (a smoothstep in cos) from a projection bitmap, keeps our profile.
        scalar(emitter, "cutoff_angle", light.cone_angle_deg)
        scalar(emitter, "beam_width", light.cone_angle_deg)
        axis = np.subtract(light.look_at, light.position)
        up = frame(axis)[:, 0]
        look_at(emitter, light.position, light.look_at, up)
        if light.falloff_deg > 0.0:
            relative = f"textures/spot-{i}.exr"
            write_image(self.out / relative, spot_texture(light.cone_angle_deg, light.falloff_deg))
            texture = child(emitter, "texture", type="bitmap", name="texture")
            child(texture, "string", name="filename", value=relative)
            child(texture, "boolean", name="raw", value="true")
            child(texture, "string", name="wrap_mode", value="clamp")
            self.note(
                f"spot falloff of lights[{i}]",
                "proxy",
                f"our smoothstep falloff as a {SPOT_TEXTURE_SIZE}x{SPOT_TEXTURE_SIZE} projection "
                "bitmap (bilinear, within 1e-4); Mitsuba's own falloff is linear in angle",
            )

    def _sun(self, root: ET.Element, i: int, light: fmt.SunLight) -> None:
        to_sun = np.asarray(light.to_sun, dtype=np.float64)
        if light.angular_radius_deg == 0.0:
            emitter = child(root, "emitter", type="directional")
            child(emitter, "vector", name="direction", value=triple(-to_sun))
            rgb(emitter, "irradiance", light.irradiance)
            return
        theta = math.radians(light.angular_radius_deg)
        distance = SUN_DISTANCE * self.radius
        disc_radius = distance * math.tan(theta)
        # The disc hides the sky behind it: add the sky's radiance there to the disc's own.
        one_minus_cos = 2.0 * math.sin(0.5 * theta) ** 2
        sin2 = one_minus_cos * (2.0 - one_minus_cos)
        radiance = np.asarray(light.irradiance) / (math.pi * sin2)
        radiance = radiance + sky_radiance(self.state.sky, to_sun)
        matrix = np.eye(4)
        matrix[:3, :3] = frame(-to_sun) * np.array([disc_radius, disc_radius, 1.0])
        matrix[:3, 3] = self.center + distance * to_sun
        shape = child(root, "shape", type="disk")
        to_world(shape, matrix)
        black = child(shape, "bsdf", type="diffuse")
        rgb(black, "reflectance", (0.0, 0.0, 0.0))
        emitter = child(shape, "emitter", type="area")
        rgb(emitter, "radiance", radiance)
        self.far = max(self.far, 4.0 * distance)
        detail = (
            f"a disc of radius D tan(theta) at D = {SUN_DISTANCE:g} scene radii (Mitsuba's "
            "directional light has no radius): parallax below 1e-4 rad"
        )
        if isinstance(self.state.sky, fmt.GradientSky):
            detail += "; the gradient sky behind the disc is replaced by its value at the centre"
        elif isinstance(self.state.sky, EnvironmentMap):
            detail += "; the environment map behind the disc is replaced by its value at the centre"
        self.note(f"sun lights[{i}] with a radius", "proxy", detail)

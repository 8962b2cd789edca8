"""The scene format's skies and point, spot and sun lights; part of ``tracer.scene.format``,
through which they are used."""

from typing import Annotated, Literal

import numpy as np
from pydantic import AfterValidator, Field, Tag, model_validator

from tracer.maths import portable
from tracer.scene.format_base import (
    FilePath,
    Finite,
    NonNegative,
    Radiance,
    Strict,
    Vec3,
    type_tag,
)


class ConstantSky(Strict):
    """The same radiance from every direction no surface blocks."""

    type: Literal["constant"] = "constant"
    radiance: Radiance = Field(
        default=(0.0, 0.0, 0.0), description="Radiance from every direction nothing blocks"
    )


class GradientSky(Strict):
    """Radiance by elevation (+y is up): ``horizon`` at the horizon to ``zenith`` straight up,
    linear in the sine of the elevation; ``ground`` from every direction below the horizon."""

    type: Literal["gradient"]
    zenith: Radiance
    horizon: Radiance
    ground: Radiance = (0.0, 0.0, 0.0)


class EnvironmentSky(Strict):
    """An equirectangular (latitude-longitude) HDR image of the radiance at infinity: +y is up,
    the image's top row looks straight up and its bottom row straight down, ``u`` (left to
    right) runs along the azimuth, and the image centre looks along -z (the default camera's
    view); docs/scene-format.md. Light samples pick its bright pixels more often (importance
    sampling by luminance)."""

    type: Literal["environment"]
    file: FilePath = Field(
        description="An OpenEXR (.exr, R, G and B channels) or NumPy (.npy, float (H, W, 3)) "
        "image of linear RGB radiance, relative to the scene file and inside its directory",
    )
    scale: NonNegative = Field(default=1.0, description="Factor on the image's radiance")
    rotation: Finite = Field(
        default=0.0,
        description="Degrees about the up axis (+y), counter-clockwise seen from above (the "
        "sense of an object's rotate about y)",
    )


Sky = Annotated[
    Annotated[ConstantSky, Tag("constant")]
    | Annotated[GradientSky, Tag("gradient")]
    | Annotated[EnvironmentSky, Tag("environment")],
    type_tag("constant", "gradient", "environment"),
]


def _unit_direction(value):
    v = np.asarray(value, dtype=np.float64)
    norm = portable.norm(v)
    if not norm > 0.0 or not np.isfinite(norm):
        raise ValueError("a direction must be a non-zero finite vector")
    return tuple(float(c) for c in v / norm)


Direction = Annotated[Vec3, AfterValidator(_unit_direction)]


class PointLight(Strict):
    """Light from one point, the same intensity in every direction."""

    type: Literal["point"]
    position: Vec3
    intensity: Radiance = Field(description="Radiant intensity, linear RGB (W sr^-1)")


class SpotLight(Strict):
    """A point light restricted to a cone about the direction from ``position`` to
    ``look_at``: full intensity out to ``cone_angle_deg - falloff_deg`` from the axis, then a
    smooth falloff to zero at ``cone_angle_deg`` (pbrt-v4's smoothstep)."""

    type: Literal["spot"]
    position: Vec3
    look_at: Vec3
    intensity: Radiance = Field(description="Radiant intensity on the axis (W sr^-1)")
    cone_angle_deg: float = Field(default=30.0, gt=0.0, le=90.0)
    falloff_deg: float = Field(default=5.0, ge=0.0, le=90.0)

    @model_validator(mode="after")
    def _check(self) -> "SpotLight":
        if not portable.norm(np.subtract(self.look_at, self.position)) > 0.0:
            raise ValueError("look_at must differ from position")
        if self.falloff_deg > self.cone_angle_deg:
            raise ValueError("falloff_deg must not exceed cone_angle_deg")
        return self


class SunLight(Strict):
    """A distant disc: light from directions within ``angular_radius_deg`` of ``to_sun``,
    with ``irradiance`` on a surface facing it. Radius 0 is a directional light (hard shadows);
    a radius gives soft shadows, and rays can see the disc."""

    type: Literal["sun"]
    to_sun: Direction = Field(description="Direction from the scene toward the sun")
    irradiance: Radiance = Field(
        description="Irradiance on a surface facing the sun, linear RGB (W m^-2)"
    )
    angular_radius_deg: float = Field(
        default=0.265, ge=0.0, le=45.0, description="Half-angle of the disc (the sun's: 0.265)"
    )


Light = Annotated[PointLight | SpotLight | SunLight, Field(discriminator="type")]

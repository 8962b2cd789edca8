"""The JSON scene description (format ``tilerender/1``), as pydantic models.

The JSON Schema exported from :class:`SceneFile` lives in ``docs/scene-schema.json``; the user
guide is ``docs/scene-format.md``. Every model forbids unknown keys and non-finite numbers, so a
typo or a NaN is an error at load time rather than a surprise in the image.
"""

import math
from typing import Annotated, Literal

import numpy as np
from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Discriminator,
    Field,
    Tag,
    field_validator,
    model_validator,
)

from tracer import config
from tracer.maths import portable

FORMAT = "tilerender/1"

Finite = Annotated[float, Field(allow_inf_nan=False)]
Vec3 = tuple[Finite, Finite, Finite]
Vec4Row = tuple[Finite, Finite, Finite, Finite]
Unit = Annotated[float, Field(ge=0.0, le=1.0, allow_inf_nan=False)]
NonNegative = Annotated[float, Field(ge=0.0, allow_inf_nan=False)]
Positive = Annotated[float, Field(gt=0.0, allow_inf_nan=False)]
Reflectance = tuple[Unit, Unit, Unit]
Radiance = tuple[NonNegative, NonNegative, NonNegative]


class Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Transform(Strict):
    """Placement of an object: ``matrix`` (row-major 4x4, affine), or translate/rotate/scale.

    With translate/rotate/scale the matrix is ``T @ R @ S``: scale first, then rotate about the
    x, y and z axes in that order (degrees), then translate.
    """

    translate: Vec3 = (0.0, 0.0, 0.0)
    rotate: Vec3 = Field(default=(0.0, 0.0, 0.0), description="Euler angles in degrees, XYZ order")
    scale: Finite | Vec3 = 1.0
    matrix: tuple[Vec4Row, Vec4Row, Vec4Row, Vec4Row] | None = None

    @model_validator(mode="after")
    def _check(self) -> "Transform":
        if self.matrix is not None and (
            self.translate != (0.0, 0.0, 0.0) or self.rotate != (0.0, 0.0, 0.0) or self.scale != 1.0
        ):
            raise ValueError("give either matrix or translate/rotate/scale, not both")
        m = self.to_matrix()
        if not np.array_equal(m[3], [0.0, 0.0, 0.0, 1.0]):
            raise ValueError("matrix must be affine: its last row must be [0, 0, 0, 1]")
        with np.errstate(all="ignore"):  # an overflowing determinant is refused just below
            det = portable.det3(m)
        if not np.isfinite(det) or det == 0.0:
            raise ValueError("transform is singular (zero scale or a degenerate matrix)")
        return self

    def to_matrix(self) -> np.ndarray:
        """The 4x4 float64 matrix this transform describes."""
        if self.matrix is not None:
            return np.array(self.matrix, dtype=np.float64)
        scale = np.broadcast_to(np.asarray(self.scale, dtype=np.float64), (3,))
        rx, ry, rz = (math.radians(a) for a in self.rotate)
        cx, sx, cy, sy, cz, sz = (
            math.cos(rx),
            math.sin(rx),
            math.cos(ry),
            math.sin(ry),
            math.cos(rz),
            math.sin(rz),
        )
        rot_x = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
        rot_y = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
        rot_z = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
        m = np.eye(4)
        with np.errstate(all="ignore"):  # huge scales overflow to inf: refused as singular
            m[:3, :3] = portable.chain(rot_z, rot_y, rot_x, np.diag(scale))
        m[:3, 3] = self.translate
        return m


class Texture(Strict):
    """An image that multiplies a material's base colour, looked up through the mesh's UVs with
    bilinear filtering (docs/materials.md).

    ``file`` is relative to the scene file (PNG, JPEG and the other formats Pillow reads);
    colour images are sRGB-encoded and decoded to linear on load. ``u`` runs left to right and
    ``v`` bottom to top across the image (OBJ's and OpenGL's convention; glTF files are
    converted on load)."""

    file: str = Field(min_length=1, description="Image file, relative to the scene file")
    wrap: Literal["repeat", "clamp"] = Field(
        default="repeat",
        description="Outside [0, 1]: repeat the image (tiling), or clamp to its edge texels",
    )
    scale: tuple[Positive, Positive] = Field(
        default=(1.0, 1.0), description="UVs are multiplied by this before the lookup (tiling)"
    )


class _Opaque(Strict):
    """What every opaque material has: emission (an area light), sidedness and an optional
    base-colour texture."""

    emission: Radiance = Field(
        default=(0.0, 0.0, 0.0), description="Emitted radiance, linear RGB (W sr^-1 m^-2)"
    )
    two_sided: bool = Field(
        default=True,
        description="Reflect and emit on both sides; one-sided surfaces are black from the back "
        "(the back is the side the counter-clockwise winding faces away from)",
    )
    texture: Texture | None = Field(
        default=None,
        description="An image multiplying the base colour (reflectance) through the mesh's "
        "UVs; the mesh must have UVs",
    )


class DiffuseMaterial(_Opaque):
    """Lambertian reflector, optionally emissive (an area light)."""

    type: Literal["diffuse"] = "diffuse"
    reflectance: Reflectance = (0.8, 0.8, 0.8)


class MirrorMaterial(_Opaque):
    """Perfect specular reflector: every ray leaves in the mirror direction, scaled by
    ``reflectance`` (no Fresnel term)."""

    type: Literal["mirror"]
    reflectance: Reflectance = (1.0, 1.0, 1.0)


Ior = Annotated[float, Field(gt=0.0, le=10.0, allow_inf_nan=False)]


class DielectricMaterial(Strict):
    """Smooth glass-like boundary: Fresnel reflection and refraction, total internal reflection,
    and Beer-Lambert absorption inside. Needs closed meshes whose triangles face outward (the
    front side is outside); always two-sided, never emissive."""

    type: Literal["dielectric"]
    ior: Ior = Field(default=1.5, description="Index of refraction inside / outside")
    absorption: Radiance = Field(
        default=(0.0, 0.0, 0.0),
        description="Absorption coefficient inside, per unit of scene length (Beer-Lambert)",
    )


Roughness = Annotated[float, Field(ge=0.0, le=1.0, allow_inf_nan=False)]
PositiveVec3 = tuple[Positive, Positive, Positive]


class ConductorMaterial(_Opaque):
    """Metal: GGX microfacet reflection with the conductor Fresnel term (visible-normal
    sampling); roughness 0 is a smooth metal. The Fresnel term comes from ``eta`` and ``k``
    (complex index of refraction per channel) or, if they are not given, from ``reflectance``
    (the colour at normal incidence; docs/materials.md gives the mapping)."""

    type: Literal["conductor"]
    reflectance: Reflectance | None = Field(
        default=None, description="Colour at normal incidence (default 0.9 grey)"
    )
    eta: PositiveVec3 | None = Field(default=None, description="Real part of the index")
    k: tuple[NonNegative, NonNegative, NonNegative] | None = Field(
        default=None, description="Imaginary part of the index (extinction)"
    )
    roughness: Roughness = Field(default=0.0, description="GGX alpha = roughness^2")

    @model_validator(mode="after")
    def _check(self) -> "ConductorMaterial":
        if (self.eta is None) != (self.k is None):
            raise ValueError("give eta and k together")
        if self.eta is not None and self.reflectance is not None:
            raise ValueError("give either reflectance or eta and k, not both")
        return self


class PlasticMaterial(_Opaque):
    """Coated diffuse: a Lambertian base under a dielectric coat with a GGX rough surface
    (a specular lobe with the dielectric Fresnel term, and the base's light scaled by the
    coat's transmission; docs/materials.md)."""

    type: Literal["plastic"]
    reflectance: Reflectance = Field(default=(0.5, 0.5, 0.5), description="Base colour")
    ior: Annotated[float, Field(gt=1.0, le=3.0, allow_inf_nan=False)] = Field(
        default=1.5, description="Index of refraction of the coat"
    )
    roughness: Roughness = Field(
        default=0.1, description="GGX alpha = roughness^2 (at least 0.001)"
    )


def _tag(default: str, *others: str):
    """A discriminator that reads ``type`` and takes ``default`` when it is missing."""

    def tag(value):
        if isinstance(value, dict):
            return value.get("type", default)
        return getattr(value, "type", default)

    known = ", ".join(repr(t) for t in (default, *others))
    return Discriminator(
        tag,
        custom_error_type="invalid_type_tag",
        custom_error_message=f"type must be one of {known} (default {default!r})",
    )


Material = Annotated[
    Annotated[DiffuseMaterial, Tag("diffuse")]
    | Annotated[MirrorMaterial, Tag("mirror")]
    | Annotated[DielectricMaterial, Tag("dielectric")]
    | Annotated[ConductorMaterial, Tag("conductor")]
    | Annotated[PlasticMaterial, Tag("plastic")],
    _tag("diffuse", "mirror", "dielectric", "conductor", "plastic"),
]
"""Material kinds, a union on ``type`` (``diffuse`` when it is missing); docs/materials.md."""
MATERIAL_TYPES = (
    DiffuseMaterial,
    MirrorMaterial,
    DielectricMaterial,
    ConductorMaterial,
    PlasticMaterial,
)


class MeshFile(Strict):
    """Triangles from a file (OBJ, PLY, STL, glTF, GLB), relative to the scene file."""

    type: Literal["file"] = "file"
    path: str = Field(min_length=1)


class Rectangle(Strict):
    """A rectangle centred at the origin in the xy plane, facing +z."""

    type: Literal["rectangle"]
    size: tuple[Positive, Positive] = (2.0, 2.0)


class Box(Strict):
    """An axis-aligned box centred at the origin, faces pointing outward."""

    type: Literal["box"]
    size: tuple[Positive, Positive, Positive] = (2.0, 2.0, 2.0)


class Sphere(Strict):
    """An icosphere centred at the origin."""

    type: Literal["sphere"]
    radius: Positive = 1.0
    subdivisions: int = Field(default=4, ge=0, le=config.MAX_SPHERE_SUBDIVISIONS)


class Plane(Strict):
    """A large square in the xz plane through the origin, facing +y (a ground plane)."""

    type: Literal["plane"]
    size: Positive = 100.0


Shape = Annotated[MeshFile | Rectangle | Box | Sphere | Plane, Field(discriminator="type")]


class SceneObject(Strict):
    name: str = Field(default="", max_length=200)
    shape: Shape | str = Field(
        description="A built-in shape, a mesh file, or a mesh file's path as a plain string"
    )
    material: str | None = Field(
        default=None,
        min_length=1,
        description="Name of a material; left out for a mesh file, the file's own materials "
        "(glTF PBR or OBJ/MTL, docs/materials.md)",
    )
    transform: Transform = Transform()
    kind: Literal["static", "rigid", "deformable", "dynamic"] = Field(
        default="static",
        description="static: never moves (baked into one BVH); rigid: moves as a whole; "
        "deformable: its vertices move; dynamic: its topology changes",
    )
    parent: str | None = Field(
        default=None,
        description="Name of an earlier object: this object's transform is relative to it",
    )

    @field_validator("shape", mode="before")
    @classmethod
    def _path_shorthand(cls, value):
        return {"type": "file", "path": value} if isinstance(value, str) else value

    @model_validator(mode="after")
    def _check(self) -> "SceneObject":
        if self.material is None and not isinstance(self.shape, MeshFile):
            raise ValueError("a built-in shape needs a material (only a mesh file may use its own)")
        return self


class Camera(Strict):
    position: Vec3 = (0.0, 0.0, 5.0)
    look_at: Vec3 = (0.0, 0.0, 0.0)
    up: Vec3 = (0.0, 1.0, 0.0)
    vfov_deg: float = Field(default=40.0, gt=0.0, lt=180.0, description="Vertical field of view")
    width: int = Field(default=640, ge=1, le=config.MAX_IMAGE_SIDE)
    height: int = Field(default=480, ge=1, le=config.MAX_IMAGE_SIDE)
    aperture_radius: NonNegative = Field(
        default=0.0, description="Radius of the thin lens in scene units; 0 is a pinhole"
    )
    focus_distance: Positive | None = Field(
        default=None,
        description="Distance of the plane in focus along the view direction "
        "(default: the distance from position to look_at)",
    )

    @model_validator(mode="after")
    def _check(self) -> "Camera":
        if self.width * self.height > config.MAX_PIXELS:
            raise ValueError(f"width * height must be at most {config.MAX_PIXELS} pixels")
        forward = np.subtract(self.look_at, self.position)
        if not portable.norm(forward) > 0.0:
            raise ValueError("look_at must differ from position")
        if not portable.norm(portable.cross(portable.normalized(forward), self.up)) > 1e-9:
            raise ValueError("up must not be parallel to the viewing direction")
        return self


INTEGRATORS = ("path", "direct", "whitted", "ao", "albedo", "normal", "depth", "cost")
EffectName = Literal[
    "area_lights",
    "point_lights",
    "sun",
    "sky",
    "shadows",
    "indirect",
    "refraction",
    "absorption",
    "textures",
]
"""Effects a user may switch off (docs/effects.md)."""


class RenderSettings(Strict):
    spp: int = Field(default=64, ge=1, le=config.MAX_SPP, description="Samples per pixel")
    max_depth: int = Field(
        default=8,
        ge=1,
        le=config.MAX_DEPTH,
        description="Path vertices after the camera: 1 = emitters only, 2 = direct light",
    )
    rr_depth: int = Field(
        default=5,
        ge=1,
        le=config.MAX_DEPTH,
        description="Russian roulette starts at paths of this many vertices",
    )
    seed: int = Field(default=0, ge=0, lt=2**63)
    integrator: Literal[INTEGRATORS] = Field(
        default="path",
        description="path (NEE + MIS + Russian roulette), direct (one bounce), whitted (direct "
        "light and perfect specular recursion), ao (ambient occlusion), or a debug output: "
        "albedo, normal, depth, cost",
    )
    effects: dict[EffectName, bool] = Field(
        default_factory=dict,
        description="Effects switched off on purpose (name -> false); docs/effects.md",
    )
    effect_plan: bool = Field(
        default=True,
        description="Simulate only the effects the scene needs; false runs every effect "
        "(the same image in expectation, slower: for checking the plan)",
    )
    ao_samples: int = Field(
        default=4, ge=1, le=1024, description="Ambient occlusion rays per camera sample"
    )
    ao_distance: Positive = Field(
        default=0.1,
        description="Ambient occlusion ray length, as a fraction of the scene's bounding-box "
        "diagonal",
    )

    @field_validator("effects")
    @classmethod
    def _only_off(cls, value):
        on = sorted(name for name, enabled in value.items() if enabled)
        if on:
            raise ValueError(
                f"effects can only be switched off (false); {', '.join(on)} would be on anyway "
                "where the scene needs it"
            )
        return value


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
    file: str = Field(
        min_length=1,
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
    _tag("constant", "gradient", "environment"),
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


MAX_FRAMES = 100_000
"""Most frames an animation may have."""

Time = Annotated[float, Field(ge=0.0, allow_inf_nan=False, description="Seconds from frame 0")]
Vec4 = tuple[Finite, Finite, Finite, Finite]


def _strictly_increasing(keys: list) -> list:
    """A track's check: at least one key, times strictly increasing."""
    if not keys:
        raise ValueError("a track needs at least one key")
    for i in range(1, len(keys)):
        if not keys[i].time > keys[i - 1].time:
            raise ValueError(
                f"key times must increase strictly: key {i} (time {keys[i].time}) does not "
                f"come after key {i - 1} (time {keys[i - 1].time})"
            )
    return keys


class ObjectKeyframe(Strict):
    """A keyframe of an object's transform (relative to its parent, like ``transform``).

    Omitted fields take the value of the object's own ``transform`` (its translate, rotation and
    scale; a ``matrix`` transform is split into those). ``rotate`` (Euler angles, as in
    ``transform``) and ``rotation`` (a quaternion) are alternatives.
    """

    time: Time
    translate: Vec3 | None = None
    rotate: Vec3 | None = Field(default=None, description="Euler angles in degrees, XYZ order")
    rotation: Vec4 | None = Field(
        default=None, description="Unit quaternion (w, x, y, z); normalised on load"
    )
    scale: Finite | Vec3 | None = None

    @field_validator("rotation")
    @classmethod
    def _normalise(cls, value):
        if value is None:
            return value
        q = np.asarray(value, dtype=np.float64)
        largest = np.max(np.abs(q))
        if largest == 0.0:
            raise ValueError("rotation must be a non-zero quaternion (w, x, y, z)")
        q = q / largest  # no overflow in the norm
        return tuple(float(c) for c in q / portable.norm(q))

    @field_validator("scale")
    @classmethod
    def _non_zero(cls, value):
        if value is not None and 0.0 in np.atleast_1d(value):
            raise ValueError("scale must not be zero (a zero scale is singular)")
        return value

    @model_validator(mode="after")
    def _check(self) -> "ObjectKeyframe":
        if self.rotate is not None and self.rotation is not None:
            raise ValueError(
                "give either rotate (Euler angles) or rotation (a quaternion), not both"
            )
        return self


class CameraKeyframe(Strict):
    """A keyframe of the camera; omitted fields take the value of the scene's ``camera``."""

    time: Time
    position: Vec3 | None = None
    look_at: Vec3 | None = None
    up: Vec3 | None = None
    vfov_deg: float | None = Field(
        default=None, gt=0.0, lt=180.0, description="Vertical field of view"
    )


ObjectTrack = Annotated[
    list[ObjectKeyframe],
    Field(json_schema_extra={"minItems": 1}),
    AfterValidator(_strictly_increasing),
]
CameraTrack = Annotated[
    list[CameraKeyframe],
    Field(json_schema_extra={"minItems": 1}),
    AfterValidator(_strictly_increasing),
]


class AnimationSettings(Strict):
    """Keyframe tracks for objects (by name) and the camera, played at ``fps`` for ``frames``.

    Frame ``f`` shows time ``f / fps``; between keys values are interpolated (rotations by
    slerp), before the first key and after the last a track holds still.
    """

    fps: Positive = Field(default=24.0, description="Frames per second")
    frames: int = Field(ge=1, le=MAX_FRAMES, description="Number of frames (required)")
    objects: dict[str, ObjectTrack] = Field(
        default_factory=dict,
        description="Object name -> keys; the object must be named uniquely and not be static",
    )
    camera: CameraTrack | None = Field(default=None, description="Camera keys")


class SceneFile(Strict):
    """A tilerender scene: objects with materials, a camera, render settings, a sky and an
    optional keyframe animation."""

    format: Literal["tilerender/1"] = FORMAT
    camera: Camera = Camera()
    render: RenderSettings = RenderSettings()
    sky: Sky = ConstantSky()
    lights: list[Light] = Field(
        default_factory=list,
        description="Point, spot and sun lights (emitting surfaces are materials with emission)",
    )
    materials: dict[str, Material] = Field(min_length=1)
    objects: list[SceneObject] = Field(min_length=1)
    animation: AnimationSettings | None = None

    @model_validator(mode="after")
    def _check_references(self) -> "SceneFile":
        for i, obj in enumerate(self.objects):
            if obj.material is not None and obj.material not in self.materials:
                known = ", ".join(sorted(self.materials))
                raise ValueError(
                    f"objects[{i}] uses material {obj.material!r}, which is not defined "
                    f"(defined: {known})"
                )
        return self


def override(model: Strict, **changes) -> Strict:
    """A copy of ``model`` with ``changes`` (``None`` values ignored), validated like the input.

    Raises pydantic's ValidationError for a value the model would refuse in a file.
    """
    data = model.model_dump()
    data.update({k: v for k, v in changes.items() if v is not None})
    return type(model).model_validate(data)

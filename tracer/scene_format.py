"""The JSON scene description (format ``tilerender/1``), as pydantic models.

The JSON Schema exported from :class:`SceneFile` lives in ``docs/scene-schema.json``; the user
guide is ``docs/scene-format.md``. Every model forbids unknown keys and non-finite numbers, so a
typo or a NaN is an error at load time rather than a surprise in the image.
"""

from typing import Annotated, Literal

import numpy as np
from pydantic import AfterValidator, BaseModel, ConfigDict, Field, field_validator, model_validator

from tracer import config

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
            det = np.linalg.det(m[:3, :3])
        if not np.isfinite(det) or det == 0.0:
            raise ValueError("transform is singular (zero scale or a degenerate matrix)")
        return self

    def to_matrix(self) -> np.ndarray:
        """The 4x4 float64 matrix this transform describes."""
        if self.matrix is not None:
            return np.array(self.matrix, dtype=np.float64)
        scale = np.broadcast_to(np.asarray(self.scale, dtype=np.float64), (3,))
        rx, ry, rz = np.radians(self.rotate)
        cx, sx, cy, sy, cz, sz = (
            np.cos(rx),
            np.sin(rx),
            np.cos(ry),
            np.sin(ry),
            np.cos(rz),
            np.sin(rz),
        )
        rot_x = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
        rot_y = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
        rot_z = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
        m = np.eye(4)
        with np.errstate(all="ignore"):  # huge scales overflow to inf: refused as singular
            m[:3, :3] = rot_z @ rot_y @ rot_x @ np.diag(scale)
        m[:3, 3] = self.translate
        return m


class DiffuseMaterial(Strict):
    """Lambertian reflector, optionally emissive (an area light)."""

    type: Literal["diffuse"] = "diffuse"
    reflectance: Reflectance = (0.8, 0.8, 0.8)
    emission: Radiance = Field(
        default=(0.0, 0.0, 0.0), description="Emitted radiance, linear RGB (W sr^-1 m^-2)"
    )
    two_sided: bool = Field(
        default=True,
        description="Reflect and emit on both sides; one-sided surfaces are black from the back "
        "(the back is the side the counter-clockwise winding faces away from)",
    )


Material = DiffuseMaterial
"""Material kinds; more join as a discriminated union on ``type`` (docs/scene-format.md)."""


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
    material: str = Field(min_length=1)
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


class Camera(Strict):
    position: Vec3 = (0.0, 0.0, 5.0)
    look_at: Vec3 = (0.0, 0.0, 0.0)
    up: Vec3 = (0.0, 1.0, 0.0)
    vfov_deg: float = Field(default=40.0, gt=0.0, lt=180.0, description="Vertical field of view")
    width: int = Field(default=640, ge=1, le=config.MAX_IMAGE_SIDE)
    height: int = Field(default=480, ge=1, le=config.MAX_IMAGE_SIDE)

    @model_validator(mode="after")
    def _check(self) -> "Camera":
        if self.width * self.height > config.MAX_PIXELS:
            raise ValueError(f"width * height must be at most {config.MAX_PIXELS} pixels")
        forward = np.subtract(self.look_at, self.position)
        if not np.linalg.norm(forward) > 0.0:
            raise ValueError("look_at must differ from position")
        if not np.linalg.norm(np.cross(forward / np.linalg.norm(forward), self.up)) > 1e-9:
            raise ValueError("up must not be parallel to the viewing direction")
        return self


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


class SkySettings(Strict):
    radiance: Radiance = Field(
        default=(0.0, 0.0, 0.0), description="Radiance from every direction nothing blocks"
    )


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
        return tuple(float(c) for c in q / np.linalg.norm(q))

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
    sky: SkySettings = SkySettings()
    materials: dict[str, Material] = Field(min_length=1)
    objects: list[SceneObject] = Field(min_length=1)
    animation: AnimationSettings | None = None

    @model_validator(mode="after")
    def _check_references(self) -> "SceneFile":
        for i, obj in enumerate(self.objects):
            if obj.material not in self.materials:
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

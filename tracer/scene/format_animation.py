"""The scene format's keyframe animation: tracks of object and camera keys; part of
``tracer.scene.format``, through which they are used."""

from typing import Annotated

import numpy as np
from pydantic import AfterValidator, Field, field_validator, model_validator

from tracer.maths import portable
from tracer.scene.format_base import Finite, Name, Positive, Strict, Vec3

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
    objects: dict[Name, ObjectTrack] = Field(
        default_factory=dict,
        description="Object name -> keys; the object must be named uniquely and not be static",
    )
    camera: CameraTrack | None = Field(default=None, description="Camera keys")

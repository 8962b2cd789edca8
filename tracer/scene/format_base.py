"""The base of every model of the scene format (``tracer.scene.format``): the strict model,
the name and number types, an object's placement (``Transform``) and the ``type``-tag
discriminator."""

import math
from typing import Annotated

import numpy as np
from pydantic import BaseModel, ConfigDict, Discriminator, Field, model_validator

from tracer.maths import portable

MAX_NAME = 200
"""Characters of a name the scene chooses: a material, an object, an object's parent, an
animated object (and, in commits, a mesh or a node). A name is stored with the scene and
returned by every inspection of it, so it is short."""
MAX_PATH = 1024
"""Characters of a file reference (a mesh, a texture, an environment image)."""

Name = Annotated[str, Field(min_length=1, max_length=MAX_NAME)]
FilePath = Annotated[str, Field(min_length=1, max_length=MAX_PATH)]

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


def type_tag(default: str, *others: str):
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

"""The field types of scene operations (``tracer.scene.ops``): node references and ids, and
the validated mesh arrays (vertices, faces, UVs, normals) an operation may carry. A bad value
is a pydantic error with a message that names what is wrong."""

from typing import Annotated

import numpy as np
from pydantic import Field, PlainValidator
from pydantic_core import PydanticCustomError

from tracer.scene import format as fmt
from tracer.scene.model import frozen_array

INT64_MAX = 2**63 - 1
"""The largest node id and face index (both are stored as int64)."""


def invalid(message: str) -> PydanticCustomError:
    return PydanticCustomError("invalid_value", message)


def _node_ref(value) -> int | str:
    if isinstance(value, str) and 0 < len(value) <= fmt.MAX_NAME:
        return value
    if isinstance(value, int | np.integer) and not isinstance(value, bool):
        return int(value)
    raise invalid(
        "a node is referred to by its id (an integer) or its name (a string of at most "
        f"{fmt.MAX_NAME} characters)"
    )


def _node_id(value) -> int:
    if isinstance(value, int | np.integer) and not isinstance(value, bool):
        if 0 <= value <= INT64_MAX:
            return int(value)
    raise invalid(f"a node id is an integer from 0 to {INT64_MAX}")


def _mesh_array(value, what: str, kinds: str, kind_message: str) -> np.ndarray:
    try:
        array = np.asarray(value)
    except (ValueError, TypeError):
        raise invalid(f"{what} must be a rectangular (N, 3) array") from None
    if array.ndim != 2 or array.shape[1] != 3 or array.shape[0] == 0:
        raise invalid(f"{what} must have shape (N, 3) with N >= 1, not {array.shape}")
    if array.dtype.kind not in kinds:
        raise invalid(kind_message)
    return array


def _vertices(value) -> np.ndarray:
    array = _mesh_array(value, "vertices", "iuf", "vertex coordinates must be numbers")
    array = frozen_array(array, np.float64)
    if not np.isfinite(array).all():
        raise invalid("vertices must be finite (no NaN or infinity)")
    return array


def _faces(value) -> np.ndarray:
    array = _mesh_array(value, "faces", "iu", "face indices must be integers")
    if array.min() < 0 or array.max() > INT64_MAX:
        raise invalid("face indices must be non-negative 64-bit integers")
    return frozen_array(array, np.int64)


def _uvs(value) -> np.ndarray:
    try:
        array = np.asarray(value)
    except (ValueError, TypeError):
        raise invalid("uvs must be a rectangular (N, 2) array") from None
    if array.ndim != 2 or array.shape[1] != 2:
        raise invalid(f"uvs must have shape (N, 2), not {array.shape}")
    if array.dtype.kind not in "iuf":
        raise invalid("uvs must be numbers")
    array = frozen_array(array, np.float64)
    if not np.isfinite(array).all():
        raise invalid("uvs must be finite (no NaN or infinity)")
    return array


def _normals(value) -> np.ndarray:
    array = _mesh_array(value, "normals", "iuf", "normals must be numbers")
    array = frozen_array(array, np.float64)
    if not np.isfinite(array).all():
        raise invalid("normals must be finite (no NaN or infinity)")
    return array


NodeRef = Annotated[int | str, PlainValidator(_node_ref)]
NodeId = Annotated[int, PlainValidator(_node_id)]
Name = fmt.Name
NodeName = Annotated[str, Field(max_length=fmt.MAX_NAME)]
Vertices = Annotated[np.ndarray, PlainValidator(_vertices)]
"""float64 (V, 3), read-only; given as nested lists or any numeric array."""
Faces = Annotated[np.ndarray, PlainValidator(_faces)]
"""int64 (F, 3), read-only; given as nested lists or any integer array."""
UVs = Annotated[np.ndarray, PlainValidator(_uvs)]
"""float64 (V, 2), read-only: texture coordinates per vertex."""
Normals = Annotated[np.ndarray, PlainValidator(_normals)]
"""float64 (V, 3), read-only: shading normals per vertex (unit length once in a mesh)."""

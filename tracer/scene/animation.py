"""Keyframe animation: evaluating :class:`~tracer.scene.model.Animation` tracks at a time.

A node's local transform is ``T @ R @ S`` with translation and scale interpolated linearly and
the rotation by spherical linear interpolation on the shorter arc. The camera's position, target,
up vector and field of view are interpolated linearly (the up vector re-normalised). Before the
first key and after the last the track holds still, and at a key's time the result is exactly
that key's value: interpolation only runs strictly between two keys. Key times never decrease
(``tracer.scene.checks``); a repeated time is a jump, and at that time the later key holds.
"""

import bisect
import math
from collections.abc import Sequence

import numpy as np
import pydantic

from tracer.errors import SceneError
from tracer.maths import portable
from tracer.scene import format as fmt
from tracer.scene.model import Animation, CameraKey, NodeKey, SceneState
from tracer.scene.ops import Op, SetCamera, SetTransform

Quaternion = tuple[float, float, float, float]
"""(w, x, y, z)."""


def _normalised(vector) -> np.ndarray:
    vector = np.asarray(vector, dtype=np.float64)
    return vector / portable.norm(vector)


def rotation_matrix(q: Sequence[float]) -> np.ndarray:
    """The 3x3 rotation of quaternion ``q`` = (w, x, y, z), normalised first."""
    w, x, y, z = _normalised(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def trs_matrix(
    translate: Sequence[float], rotation: Sequence[float], scale: Sequence[float]
) -> np.ndarray:
    """The affine 4x4 ``T @ R @ S`` (float64); ``rotation`` is a quaternion (w, x, y, z)."""
    matrix = np.eye(4)
    matrix[:3, :3] = rotation_matrix(rotation) * np.asarray(scale, dtype=np.float64)
    matrix[:3, 3] = translate
    return matrix


def slerp(a: Sequence[float], b: Sequence[float], u: float) -> Quaternion:
    """The unit quaternion a fraction ``u`` of the way from ``a`` to ``b`` on the shorter arc."""
    a, b = _normalised(a), _normalised(b)
    dot = portable.dot(a, b)
    if dot < 0.0:  # q and -q are the same rotation: go the short way round
        b, dot = -b, -dot
    if dot > 0.9995:  # nearly parallel: sin(theta) ~ 0, a normalised lerp is exact enough
        q = (1.0 - u) * a + u * b
    else:
        theta = math.acos(dot)
        q = (math.sin((1.0 - u) * theta) * a + math.sin(u * theta) * b) / math.sin(theta)
    return tuple(float(c) for c in _normalised(q))


def _lerp(a: Sequence[float], b: Sequence[float], u: float) -> tuple[float, ...]:
    return tuple((1.0 - u) * x + u * y for x, y in zip(a, b, strict=True))


def _bracket(keys: Sequence, time: float) -> tuple[int, float]:
    """``(i, u)``: the value is key ``i``'s when ``u == 0``, else between keys i and i+1."""
    if not keys:
        raise SceneError("an animation track has no keys")
    if not math.isfinite(time):
        raise SceneError(f"animation time must be finite, not {time}")
    i = bisect.bisect_right(keys, time, key=lambda key: key.time) - 1
    if i < 0:
        return 0, 0.0
    if i == len(keys) - 1 or keys[i].time == time:
        return i, 0.0
    t0, t1 = keys[i].time, keys[i + 1].time
    return i, (time - t0) / (t1 - t0)


def node_transform(keys: Sequence[NodeKey], time: float) -> np.ndarray:
    """A node track's local transform at ``time`` seconds (4x4 float64)."""
    i, u = _bracket(keys, time)
    a = keys[i]
    if u == 0.0:
        return trs_matrix(a.translate, a.rotation, a.scale)
    b = keys[i + 1]
    return trs_matrix(
        _lerp(a.translate, b.translate, u),
        slerp(a.rotation, b.rotation, u),
        _lerp(a.scale, b.scale, u),
    )


def camera_at(keys: Sequence[CameraKey], time: float, base: fmt.Camera | None = None) -> fmt.Camera:
    """The camera at ``time`` seconds; image size from ``base`` (default: the model default)."""
    i, u = _bracket(keys, time)
    a = keys[i]
    if u == 0.0:
        position, look_at, up, vfov = a.position, a.look_at, a.up, a.vfov_deg
    else:
        b = keys[i + 1]
        position, look_at = _lerp(a.position, b.position, u), _lerp(a.look_at, b.look_at, u)
        up = _lerp(a.up, b.up, u)
        length = math.hypot(*up)
        if length == 0.0:
            raise SceneError(f"camera at t={time}: the up vectors of two keys cancel out")
        up = tuple(c / length for c in up)
        vfov = (1.0 - u) * a.vfov_deg + u * b.vfov_deg
    size = base or fmt.Camera()
    try:
        return fmt.Camera(
            position=position,
            look_at=look_at,
            up=up,
            vfov_deg=vfov,
            width=size.width,
            height=size.height,
            aperture_radius=size.aperture_radius,
            focus_distance=size.focus_distance,
        )
    except pydantic.ValidationError as error:
        raise SceneError(f"camera at t={time}: {_problem(error)}") from None


def _problem(error: pydantic.ValidationError) -> str:
    """The first problem of a model-level validation error, as a phrase."""
    return error.errors()[0]["msg"].removeprefix("Value error, ")


def frame_time(animation: Animation, frame: int) -> float:
    """The time of ``frame`` (0 <= frame < animation.frames), in seconds."""
    integer = isinstance(frame, int | np.integer) and not isinstance(frame, bool)
    if not integer or not 0 <= frame < animation.frames:
        raise SceneError(f"frame {frame!r} is not one of the animation's {animation.frames}")
    return int(frame) / animation.fps


def animation_ops(state: SceneState, frame: int) -> list[Op]:
    """The operations that move ``state`` to its animation's pose at ``frame``: ``set_transform``
    for each animated node (in id order) and ``set_camera``, each only if the value changes."""
    animation = state.animation
    if animation is None:
        return []
    time = frame_time(animation, frame)
    ops: list[Op] = []
    for node_id in sorted(animation.nodes):
        if node_id not in state.nodes:
            raise SceneError(f"the animation moves node {node_id}, which does not exist")
        matrix = node_transform(animation.nodes[node_id], time)
        if not np.array_equal(matrix, state.nodes[node_id].transform):
            try:
                transform = fmt.Transform(matrix=matrix.tolist())
            except pydantic.ValidationError as error:
                raise SceneError(f"node {node_id} at frame {frame}: {_problem(error)}") from None
            ops.append(SetTransform(node=node_id, transform=transform))
    if animation.camera:
        camera = camera_at(animation.camera, time, state.camera)
        if camera != state.camera:
            ops.append(SetCamera(camera=camera))
    return ops


def _quaternion_product(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    pw, px, py, pz = p
    qw, qx, qy, qz = q
    return np.array(
        [
            pw * qw - px * qx - py * qy - pz * qz,
            pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx,
            pw * qz + px * qy - py * qx + pz * qw,
        ]
    )


def quaternion_from_euler_xyz(degrees: Sequence[float]) -> Quaternion:
    """The quaternion of ``scene_format.Transform``'s rotation: about x, then y, then z
    (R = Rz @ Ry @ Rx), angles in degrees."""
    halves = np.radians(np.asarray(degrees, dtype=np.float64)) / 2.0
    axes = np.eye(3)
    q = np.array([1.0, 0.0, 0.0, 0.0])
    for axis, half in zip(axes, halves, strict=True):
        q = _quaternion_product(np.concatenate(([math.cos(half)], math.sin(half) * axis)), q)
    return tuple(float(c) for c in q)


def _quaternion_from_rotation(r: np.ndarray) -> np.ndarray:
    """Shepperd's method: pivot on the largest of w, x, y, z for stability."""
    trace = r[0, 0] + r[1, 1] + r[2, 2]
    pivot = int(np.argmax([trace, r[0, 0], r[1, 1], r[2, 2]]))
    if pivot == 0:
        s = 2.0 * math.sqrt(1.0 + trace)
        q = [s / 4, (r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s]
    elif pivot == 1:
        s = 2.0 * math.sqrt(1.0 + r[0, 0] - r[1, 1] - r[2, 2])
        q = [(r[2, 1] - r[1, 2]) / s, s / 4, (r[0, 1] + r[1, 0]) / s, (r[0, 2] + r[2, 0]) / s]
    elif pivot == 2:
        s = 2.0 * math.sqrt(1.0 - r[0, 0] + r[1, 1] - r[2, 2])
        q = [(r[0, 2] - r[2, 0]) / s, (r[0, 1] + r[1, 0]) / s, s / 4, (r[1, 2] + r[2, 1]) / s]
    else:
        s = 2.0 * math.sqrt(1.0 - r[0, 0] - r[1, 1] + r[2, 2])
        q = [(r[1, 0] - r[0, 1]) / s, (r[0, 2] + r[2, 0]) / s, (r[1, 2] + r[2, 1]) / s, s / 4]
    q = _normalised(q)
    return -q if q[0] < 0.0 else q


def matrix_to_trs(matrix) -> tuple[tuple[float, ...], Quaternion, tuple[float, ...]]:
    """``(translate, rotation, scale)`` with ``trs_matrix(...)`` equal to ``matrix`` up to
    rounding. A mirroring matrix gets a negative x scale; a sheared one cannot be split this way
    and raises SceneError."""
    m = np.asarray(matrix, dtype=np.float64)
    if m.shape != (4, 4) or not np.isfinite(m).all() or not np.array_equal(m[3], [0, 0, 0, 1]):
        raise SceneError("matrix_to_trs needs a finite affine 4x4 matrix")
    linear = m[:3, :3]
    scale = np.linalg.norm(linear, axis=0)
    if not (scale > 0.0).all():
        raise SceneError("matrix_to_trs: the matrix is singular")
    if portable.det3(linear) < 0.0:
        scale[0] = -scale[0]
    rotation = linear / scale
    if not np.allclose(portable.matmul(rotation.T, rotation), np.eye(3), rtol=0.0, atol=1e-9):
        raise SceneError("matrix_to_trs: the matrix shears, so it is not T @ R @ S")
    q = _quaternion_from_rotation(rotation)
    return (
        tuple(float(c) for c in m[:3, 3]),
        tuple(float(c) for c in q),
        tuple(float(c) for c in scale),
    )

"""Keyframe evaluation (``tracer.scene.animation``): exact at keys, clamped outside, continuous,
slerp on the short arc, and the ops that pose a scene at a frame."""

import dataclasses
import itertools
import math

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from tests.scene_states import small_state, spinning_animation, translation
from tracer.errors import SceneError
from tracer.scene import animation as an
from tracer.scene import format as fmt
from tracer.scene import ops as so
from tracer.scene.model import Animation, CameraKey, NodeKey

coordinate = st.floats(-100, 100, allow_nan=False)
vec3 = st.tuples(coordinate, coordinate, coordinate)
scale = st.floats(0.1, 10).flatmap(lambda s: st.sampled_from([s, -s]))
quaternion = st.tuples(*[st.floats(-1, 1, allow_nan=False)] * 4).filter(
    lambda q: math.hypot(*q) > 0.1
)


@st.composite
def node_tracks(draw, min_size=1):
    times = sorted(draw(st.lists(st.floats(-10, 10, allow_nan=False), min_size=min_size)))
    return tuple(
        NodeKey(t, draw(vec3), draw(quaternion), draw(st.tuples(scale, scale, scale)))
        for t in times
    )


def key_matrix(key: NodeKey) -> np.ndarray:
    return an.trs_matrix(key.translate, key.rotation, key.scale)


def rotation_angle(p, q) -> float:
    """The angle of the rotation taking unit quaternion p to q (0..pi)."""
    return 2.0 * math.acos(min(1.0, abs(float(np.dot(p, q)))))


def unit(q):
    return np.asarray(q) / np.linalg.norm(q)


# --- node tracks ------------------------------------------------------------------------------


@settings(max_examples=80, derandomize=True)
@given(node_tracks())
def test_exact_at_keys_and_clamped_outside(keys):
    """At a key's time the matrix is exactly the key's (bit for bit); with repeated times the
    later key holds. Before the first key and after the last the track holds still."""
    for i, key in enumerate(keys):
        later = max(j for j, k in enumerate(keys) if k.time == key.time)
        assert np.array_equal(an.node_transform(keys, key.time), key_matrix(keys[later])), i
    assert np.array_equal(an.node_transform(keys, keys[0].time - 5.0), key_matrix(keys[0]))
    assert np.array_equal(an.node_transform(keys, keys[-1].time + 5.0), key_matrix(keys[-1]))


@settings(max_examples=80, derandomize=True)
@given(node_tracks(min_size=2))
def test_continuous_between_distinct_keys(keys):
    """Approaching a key from either side gives (nearly) the key's matrix."""
    for before, after in itertools.pairwise(keys):
        if after.time - before.time < 1e-3:
            continue
        eps = (after.time - before.time) * 1e-9
        size = 1.0 + np.abs(key_matrix(before)).max() + np.abs(key_matrix(after)).max()
        for t, key in ((before.time + eps, before), (after.time - eps, after)):
            assert np.abs(an.node_transform(keys, t) - key_matrix(key)).max() < 1e-6 * size


def test_interpolation_between_two_keys():
    """Half way through a half turn about y: a quarter turn, translation and scale half way,
    composed as T @ R @ S."""
    keys = spinning_animation().nodes[2]
    m = an.node_transform(keys, 0.5)
    quarter = fmt.Transform(translate=(3, 0, 0), rotate=(0, 90, 0), scale=1.5).to_matrix()
    np.testing.assert_allclose(m, quarter, atol=1e-15)
    np.testing.assert_array_equal(m[3], [0, 0, 0, 1])


@settings(max_examples=60, derandomize=True)
@given(vec3, st.tuples(*[st.floats(-360, 360)] * 3), st.tuples(scale, scale, scale))
def test_trs_matches_the_scene_format_transform(translate, degrees, scales):
    """trs_matrix with quaternion_from_euler_xyz is scene_format.Transform's T @ Rz Ry Rx @ S,
    and matrix_to_trs takes it apart again (a mirror becomes a negative x scale)."""
    q = an.quaternion_from_euler_xyz(degrees)
    assert math.isclose(math.hypot(*q), 1.0, rel_tol=1e-14)
    expected = fmt.Transform(translate=translate, rotate=degrees, scale=scales).to_matrix()
    np.testing.assert_allclose(an.trs_matrix(translate, q, scales), expected, atol=1e-12)
    t, r, s = an.matrix_to_trs(expected)
    np.testing.assert_allclose(an.trs_matrix(t, r, s), expected, atol=1e-12)
    assert r[0] >= 0.0 and (s[0] < 0) == (np.prod(scales) < 0) and min(s[1:]) > 0


def test_matrix_to_trs_refuses_shear_and_junk():
    shear = np.eye(4)
    shear[0, 1] = 0.5
    with pytest.raises(SceneError, match="shears"):
        an.matrix_to_trs(shear)
    with pytest.raises(SceneError, match="singular"):
        an.matrix_to_trs(np.diag([1.0, 0.0, 1.0, 1.0]))
    with pytest.raises(SceneError, match="affine"):
        an.matrix_to_trs(np.ones((4, 4)))


def test_empty_track_and_bad_time():
    with pytest.raises(SceneError, match="no keys"):
        an.node_transform((), 0.0)
    with pytest.raises(SceneError, match="finite"):
        an.node_transform(spinning_animation().nodes[2], float("nan"))


# --- slerp ------------------------------------------------------------------------------------


@settings(max_examples=150, derandomize=True)
@given(quaternion, quaternion, st.floats(0, 1))
@example((0.0, 0.0, 0.0, 1.0), (0.0, 0.0, 1.0, 0.0), 0.5)
@example((1.0, 0.0, 0.0, 0.0), (1.0, 1e-9, 0.0, 0.0), 0.3)
def test_slerp_keeps_unit_quaternions_and_takes_the_short_arc(a, b, u):
    """The result is a unit quaternion a fraction u along the shorter rotation from a to b: its
    angle from a is u times the total, from b (1 - u) times; q and -q give the same path."""
    q = an.slerp(a, b, u)
    assert math.isclose(math.hypot(*q), 1.0, rel_tol=1e-12)
    total = rotation_angle(unit(a), unit(b))
    assert total <= math.pi + 1e-12
    assert math.isclose(rotation_angle(unit(a), q), u * total, abs_tol=2e-6)
    assert math.isclose(rotation_angle(q, unit(b)), (1 - u) * total, abs_tol=2e-6)
    if abs(np.dot(unit(a), unit(b))) > 1e-6:  # at exactly 180 degrees both arcs are shortest
        flipped = an.slerp(a, tuple(-c for c in b), u)
        assert rotation_angle(q, flipped) < 1e-6


def test_slerp_ends_and_the_long_way_round():
    """From identity to a 350 degree turn about z (= -10 degrees) goes the 10 degree way."""
    identity = (1.0, 0.0, 0.0, 0.0)
    turn = an.quaternion_from_euler_xyz((0, 0, 350))
    assert an.slerp(identity, turn, 0.0) == identity
    np.testing.assert_allclose(np.abs(an.slerp(identity, turn, 1.0)), np.abs(turn), atol=1e-15)
    half = an.slerp(identity, turn, 0.5)
    expected = an.rotation_matrix(an.quaternion_from_euler_xyz((0, 0, -5)))
    np.testing.assert_allclose(an.rotation_matrix(half), expected, atol=1e-12)


# --- camera -----------------------------------------------------------------------------------


def test_camera_exact_at_keys_interpolated_between():
    keys = (
        CameraKey(0.0, (0.1, 2.0, 8.0), (0.0, 0.3, 0.0), (0.0, 1.0, 0.0), 40.0),
        CameraKey(2.0, (0.0, 2.0, 4.0), (1.0, 0.0, 0.0), (0.0, 0.0, -1.0), 61.0),
    )
    base = fmt.Camera(width=32, height=16)
    first, last = an.camera_at(keys, -1.0, base), an.camera_at(keys, 2.0, base)
    assert (first.position, first.look_at, first.up, first.vfov_deg) == (
        (0.1, 2.0, 8.0),
        (0.0, 0.3, 0.0),
        (0.0, 1.0, 0.0),
        40.0,
    )
    assert (last.position, last.up, last.vfov_deg, last.width) == (
        (0.0, 2.0, 4.0),
        (0, 0, -1),
        61,
        32,
    )
    mid = an.camera_at(keys, 1.0, base)
    np.testing.assert_allclose(mid.position, (0.05, 2.0, 6.0), rtol=1e-15)
    np.testing.assert_allclose(mid.up, (0.0, math.sqrt(0.5), -math.sqrt(0.5)), rtol=1e-15)
    assert mid.vfov_deg == 50.5 and (mid.width, mid.height) == (32, 16)
    assert an.camera_at(keys, 1.0).width == fmt.Camera().width


def test_camera_refusals():
    opposite = (
        CameraKey(0.0, (0.0, 0.0, 5.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 40.0),
        CameraKey(1.0, (0.0, 0.0, 5.0), (0.0, 0.0, 0.0), (0.0, -1.0, 0.0), 40.0),
    )
    with pytest.raises(SceneError, match="up vectors of two keys cancel"):
        an.camera_at(opposite, 0.5)
    through = (
        CameraKey(0.0, (0.0, 0.0, 5.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 40.0),
        CameraKey(1.0, (0.0, 0.0, -5.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 40.0),
    )
    with pytest.raises(SceneError, match=r"camera at t=0.5: look_at must differ"):
        an.camera_at(through, 0.5)


# --- frames -----------------------------------------------------------------------------------


def test_frame_time():
    animation = spinning_animation()
    assert [an.frame_time(animation, f) for f in range(5)] == [0.0, 0.25, 0.5, 0.75, 1.0]
    assert an.frame_time(animation, np.int64(3)) == 0.75
    for frame in (-1, 5, 1.0, True):
        with pytest.raises(SceneError, match="is not one of the animation's 5"):
            an.frame_time(animation, frame)


def test_animation_ops_pose_the_scene():
    """Frame 0 is the state's own pose (no ops); frame 2 moves the cube and the camera; applying
    the ops gives exactly the evaluated pose, after which there is nothing left to do."""
    state = small_state(animation=spinning_animation())
    assert an.animation_ops(state, 0) == []
    ops = an.animation_ops(state, 2)
    assert [op.op for op in ops] == ["set_transform", "set_camera"]
    posed = so.apply_ops(state, ops)
    assert np.array_equal(
        posed.nodes[2].transform, an.node_transform(state.animation.nodes[2], 0.5)
    )
    assert posed.camera.position == (0.0, 2.0, 6.0) and posed.camera.vfov_deg == 50.0
    assert (posed.camera.width, posed.camera.height) == (64, 48)
    assert posed.nodes[3] is state.nodes[3]
    assert an.animation_ops(posed, 2) == []
    end = so.apply_ops(posed, an.animation_ops(posed, 4))
    np.testing.assert_array_equal(end.nodes[2].transform, key_matrix(state.animation.nodes[2][-1]))


def test_animation_ops_without_animation_or_with_a_lost_node():
    assert an.animation_ops(small_state(), 0) == []
    track = (NodeKey(0.0, (0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0), (1.0, 1.0, 1.0)),)
    lost = small_state(animation=Animation(nodes={9: track}))
    with pytest.raises(SceneError, match="moves node 9, which does not exist"):
        an.animation_ops(lost, 0)
    flat = dataclasses.replace(track[0], scale=(1.0, 0.0, 1.0))
    singular = small_state(animation=Animation(nodes={1: (flat,)}))
    with pytest.raises(SceneError, match=r"node 1 at frame 0: .*singular"):
        an.animation_ops(singular, 0)
    still = small_state(
        animation=Animation(nodes={2: (dataclasses.replace(track[0], translate=(2, 0, 0)),)})
    )
    assert np.array_equal(still.nodes[2].transform, translation(2, 0, 0))
    assert an.animation_ops(still, 0) == []

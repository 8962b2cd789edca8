"""The scene file's ``animation`` section (``tracer.scene.format``, ``tracer.scene.loader``).

A section loads into an :class:`~tracer.scene.model.Animation` keyed by node id, with every key
completed from the object's transform or the scene camera; the loaded state is frame 0; the
last frame reaches the last key exactly; and every bad section is refused at load time with a
one-line message naming the problem (docs/scene-format.md, "animation").
"""

import copy
import json
import math
import re

import numpy as np
import pydantic
import pytest

from cluster.scene_graph import SceneGraph
from tests.helpers import ROOT, tiny_scene, write_json
from tracer.errors import SceneError
from tracer.scene import animation as an
from tracer.scene import format as fmt
from tracer.scene import ops as so
from tracer.scene.loader import animation_from_file, load_scene
from tracer.scene.model import CameraKey, NodeKey

FLOOR, CUBE, LAMP = 0, 1, 2
"""Node ids of the tiny scene's objects (file order)."""


def animated_scene(animation: dict, **kinds) -> dict:
    """The tiny scene with ``animation`` and the cube (and any ``kinds`` given) made rigid."""
    data = tiny_scene(animation=animation)
    kinds = {"cube": "rigid", **kinds}
    for obj in data["objects"]:
        if obj["name"] in kinds:
            obj["kind"] = kinds[obj["name"]]
    return data


def load(tmp_path, data: dict):
    return load_scene(write_json(tmp_path / "scene.json", data))


ORBIT = {
    "fps": 4,
    "frames": 9,
    "objects": {
        "cube": [
            {"time": 0.0},
            {"time": 1.0, "translate": [1, 0.5, 0], "rotate": [0, 120, 0], "scale": 2},
            {"time": 2.0, "translate": [1, 1.5, -1], "rotate": [10, 200, 30], "scale": [1, 2, 3]},
        ],
        "lamp": [
            {"time": 0.5, "rotation": [2, 0, 0, 0]},
            {"time": 1.5, "translate": [0, 4, 0], "rotation": [0, 0, 3, 4]},
        ],
    },
    "camera": [
        {"time": 0.0},
        {"time": 1.25, "position": [2, 1.5, 4], "vfov_deg": 30},
        {"time": 2.0, "position": [3, 2, 3], "look_at": [0, 1, 0], "up": [0, 0, -1]},
    ],
}
"""Frames 0..8 at 4 fps: the last frame is t = 2.0, the time of the last keys."""


def orbit_state(tmp_path):
    return load(tmp_path, animated_scene(ORBIT, lamp="rigid"))


# --- loading ----------------------------------------------------------------------------------


def test_section_loads_into_an_animation(tmp_path):
    """Tracks are keyed by node id; Euler angles become quaternion_from_euler_xyz exactly,
    quaternions are normalised, a number scale is uniform, and left-out fields are the object's
    own transform components or the scene camera's values (not the previous key's)."""
    animation = orbit_state(tmp_path).animation
    assert (animation.fps, animation.frames) == (4.0, 9)
    assert list(animation.nodes) == [CUBE, LAMP]
    q30 = an.quaternion_from_euler_xyz((0, 30, 0))  # the cube's own rotate
    assert animation.nodes[CUBE] == (
        NodeKey(0.0, (0.0, 0.5, 0.0), q30, (1.0, 1.0, 1.0)),
        NodeKey(1.0, (1.0, 0.5, 0.0), an.quaternion_from_euler_xyz((0, 120, 0)), (2.0,) * 3),
        NodeKey(2.0, (1.0, 1.5, -1.0), an.quaternion_from_euler_xyz((10, 200, 30)), (1, 2, 3)),
    )
    lamp_rotation = an.quaternion_from_euler_xyz((90, 0, 0))
    assert animation.nodes[LAMP] == (
        NodeKey(0.5, (0.0, 3.0, 0.0), (1.0, 0.0, 0.0, 0.0), (1.0, 1.0, 1.0)),
        NodeKey(1.5, (0.0, 4.0, 0.0), (0.0, 0.0, 0.6, 0.8), (1.0, 1.0, 1.0)),
    )
    assert lamp_rotation != animation.nodes[LAMP][0].rotation, "a key's rotation wins"
    up, look = (0.0, 1.0, 0.0), (0.0, 0.5, 0.0)
    assert animation.camera == (
        CameraKey(0.0, (0.0, 1.5, 4.0), look, up, 45.0),
        CameraKey(1.25, (2.0, 1.5, 4.0), look, up, 30.0),
        CameraKey(2.0, (3.0, 2.0, 3.0), (0.0, 1.0, 0.0), (0.0, 0.0, -1.0), 45.0),
    )
    for keys in animation.nodes.values():
        for key in keys:
            assert all(type(c) is float for c in (*key.translate, *key.rotation, *key.scale))


def test_without_a_section_nothing_is_animated(tmp_path):
    state = load(tmp_path, tiny_scene())
    assert state.animation is None
    assert an.animation_ops(state, 0) == []


def test_a_section_with_no_tracks_is_allowed(tmp_path):
    state = load(tmp_path, tiny_scene(animation={"frames": 3}))
    assert state.animation.fps == 24.0 and state.animation.frames == 3
    assert state.animation.nodes == {} and state.animation.camera == ()
    assert [an.animation_ops(state, f) for f in range(3)] == [[], [], []]


def test_matrix_transforms_are_split_for_left_out_fields(tmp_path):
    """A key that leaves out fields takes them from a matrix transform via matrix_to_trs; a
    shearing matrix cannot be split, which is an error only when a key needs its parts."""
    data = animated_scene({"frames": 2, "objects": {"cube": [{"time": 0, "translate": [5, 0, 0]}]}})
    matrix = fmt.Transform(translate=(1, 2, 3), rotate=(20, 40, 60), scale=(1, -2, 3)).to_matrix()
    data["objects"][CUBE]["transform"] = {"matrix": matrix.tolist()}
    state = load(tmp_path, data)
    _, rotation, scale = an.matrix_to_trs(matrix)
    assert state.animation.nodes[CUBE] == (NodeKey(0.0, (5.0, 0.0, 0.0), rotation, scale),)
    expected = matrix.copy()
    expected[:3, 3] = (5, 0, 0)
    np.testing.assert_allclose(state.nodes[CUBE].transform, expected, rtol=0, atol=1e-12)

    shear = np.eye(4)
    shear[0, 1] = 0.5
    data["objects"][CUBE]["transform"] = {"matrix": shear.tolist()}
    with pytest.raises(SceneError, match=r"matrix shears .* give all three in every key"):
        load(tmp_path, data)
    full = {"time": 0, "translate": [0, 0, 0], "rotate": [0, 0, 0], "scale": 1}
    data["animation"]["objects"]["cube"] = [full]
    assert load(tmp_path, data).animation.nodes[CUBE][0].scale == (1.0, 1.0, 1.0)


# --- frames -----------------------------------------------------------------------------------


def test_frame_zero_is_the_loaded_pose(tmp_path):
    """Animated nodes (and the camera) load posed at time 0, so frame 0 changes nothing; a key
    at t=0 overrides the object's transform, and a track starting later holds its first key."""
    state = orbit_state(tmp_path)
    nodes = state.animation.nodes
    assert np.array_equal(state.nodes[CUBE].transform, an.node_transform(nodes[CUBE], 0.0))
    assert np.array_equal(state.nodes[LAMP].transform, an.node_transform(nodes[LAMP], 0.0))
    first = nodes[LAMP][0]
    assert np.array_equal(
        state.nodes[LAMP].transform, an.trs_matrix(first.translate, first.rotation, first.scale)
    )
    unanimated = fmt.Transform().to_matrix()
    assert np.array_equal(state.nodes[FLOOR].transform, unanimated)
    assert state.camera == an.camera_at(state.animation.camera, 0.0, state.camera)
    assert an.animation_ops(state, 0) == []

    data = animated_scene({"frames": 1, "objects": {"cube": [{"time": 0, "translate": [3, 0, 0]}]}})
    moved = load(tmp_path, data)
    assert tuple(moved.nodes[CUBE].transform[:3, 3]) == (3.0, 0.0, 0.0)
    still = load(tmp_path, tiny_scene())
    np.testing.assert_allclose(
        moved.nodes[CUBE].transform[:3, :3], still.nodes[CUBE].transform[:3, :3], atol=1e-15
    )


def test_last_frame_reaches_the_last_key_exactly(tmp_path):
    state = orbit_state(tmp_path)
    last = state.animation.frames - 1
    assert an.frame_time(state.animation, last) == 2.0
    ops = an.animation_ops(state, last)
    assert [op.op for op in ops] == ["set_transform", "set_transform", "set_camera"]
    end = so.apply_ops(state, ops)
    for node_id, keys in state.animation.nodes.items():
        assert np.array_equal(end.nodes[node_id].transform, an.node_transform(keys, 2.0))
        key = keys[-1]
        expected = an.trs_matrix(key.translate, key.rotation, key.scale)
        assert np.array_equal(end.nodes[node_id].transform, expected)
    key = state.animation.camera[-1]
    assert (end.camera.position, end.camera.look_at, end.camera.up) == (
        key.position,
        key.look_at,
        key.up,
    )
    assert end.camera.vfov_deg == key.vfov_deg
    assert (end.camera.width, end.camera.height) == (12, 8)
    assert an.animation_ops(end, last) == []


def test_camera_track_is_exact_at_its_keys(tmp_path):
    """Frames 0, 5 and 8 fall on the camera keys (t = 0, 1.25, 2)."""
    state = orbit_state(tmp_path)
    for frame, key in zip((0, 5, 8), state.animation.camera, strict=True):
        assert an.frame_time(state.animation, frame) == key.time
        posed = so.apply_ops(state, an.animation_ops(state, frame))
        camera = posed.camera
        assert (camera.position, camera.look_at, camera.up, camera.vfov_deg) == (
            key.position,
            key.look_at,
            key.up,
            key.vfov_deg,
        )


def test_scene_graph_commits_the_loaded_frames(tmp_path):
    """The cluster's scene graph accepts the loaded state and commits frame poses from it."""
    state = orbit_state(tmp_path)
    graph = SceneGraph(state)
    assert graph.frame_commit(0) is None
    assert graph.frame_commit(8).version == 1
    keys = state.animation.nodes[CUBE]
    assert np.array_equal(graph.state.nodes[CUBE].transform, an.node_transform(keys, 2.0))
    assert graph.frame_commit(8) is None


# --- bad sections -----------------------------------------------------------------------------

CUBE_KEY = {"time": 0.0}

BAD_SECTIONS = [
    ("unknown object", {"objects": {"ghost": [CUBE_KEY]}}, r"no object is named 'ghost'"),
    ("unnamed object", {"objects": {"": [CUBE_KEY]}}, r"animation\.objects.*at least 1 character"),
    (
        "static object",
        {"objects": {"floor": [CUBE_KEY]}},
        r"object 'floor' is static, .*cannot move; give it \"kind\": \"rigid\"",
    ),
    (
        "equal times",
        {"objects": {"cube": [{"time": 1}, {"time": 1}]}},
        r"animation\.objects\.cube: .*key times must increase strictly: key 1 \(time 1\.0\)",
    ),
    (
        "decreasing times",
        {"objects": {"cube": [{"time": 0}, {"time": 2}, {"time": 1}]}},
        r"key times must increase strictly: key 2",
    ),
    (
        "camera times",
        {"camera": [{"time": 3}, {"time": 0}]},
        r"animation\.camera: .*key times must increase strictly",
    ),
    (
        "negative time",
        {"objects": {"cube": [{"time": -0.5}]}},
        r"animation\.objects\.cube\.0\.time: .*greater than or equal to 0",
    ),
    ("missing time", {"camera": [{"vfov_deg": 30}]}, r"animation\.camera\.0\.time: Field required"),
    (
        "zero scale",
        {"objects": {"cube": [{"time": 0, "scale": 0}]}},
        r"animation\.objects\.cube\.0\.scale: .*scale must not be zero",
    ),
    (
        "zero scale axis",
        {"objects": {"cube": [{"time": 0, "scale": [1, 0, 1]}]}},
        r"scale must not be zero",
    ),
    (
        "tiny scale",
        {"objects": {"cube": [{"time": 0, "scale": 1e-200}]}},
        r"animation\.objects\.cube: scales so small or so large make the transform singular",
    ),
    (
        "scale through zero",
        {"objects": {"cube": [{"time": 0}, {"time": 1, "scale": [1, -1, 1]}]}},
        r"the y scale changes sign between keys 0 and 1",
    ),
    (
        "zero quaternion",
        {"objects": {"cube": [{"time": 0, "rotation": [0, 0, 0, 0]}]}},
        r"animation\.objects\.cube\.0\.rotation: .*non-zero quaternion",
    ),
    (
        "short quaternion",
        {"objects": {"cube": [{"time": 0, "rotation": [1, 0, 0]}]}},
        r"animation\.objects\.cube\.0\.rotation",
    ),
    (
        "rotate and rotation",
        {"objects": {"cube": [{"time": 0, "rotate": [0, 0, 0], "rotation": [1, 0, 0, 0]}]}},
        r"give either rotate .* or rotation .*, not both",
    ),
    (
        "unknown key field",
        {"objects": {"cube": [{"time": 0, "translation": [0, 0, 0]}]}},
        r"animation\.objects\.cube\.0\.translation: unknown key",
    ),
    ("fps zero", {"fps": 0}, r"animation\.fps: Input should be greater than 0"),
    ("fps negative", {"fps": -24}, r"animation\.fps: Input should be greater than 0"),
    ("frames zero", {"frames": 0}, r"animation\.frames: .*greater than or equal to 1"),
    ("frames too many", {"frames": 100_001}, r"animation\.frames: .*less than or equal to 100000"),
    ("frames fractional", {"frames": 2.5}, r"animation\.frames: .*integer"),
    ("frames missing", {"frames": None}, r"animation\.frames: Field required"),
    ("empty object track", {"objects": {"cube": []}}, r"a track needs at least one key"),
    ("empty camera track", {"camera": []}, r"animation\.camera: .*a track needs at least one key"),
    (
        "camera key at its target",
        {"camera": [{"time": 0, "position": [0, 0.5, 0]}]},
        r"animation\.camera\.0 \(time 0\.0\): look_at must differ from position",
    ),
    (
        "camera key up along the view",
        {"camera": [{"time": 0, "position": [0, 5, 0], "look_at": [0, 0, 0]}]},
        r"animation\.camera\.0 \(time 0\.0\): up must not be parallel",
    ),
    (
        "camera key field of view",
        {"camera": [{"time": 0, "vfov_deg": 180}]},
        r"animation\.camera\.0\.vfov_deg: .*less than 180",
    ),
    (
        "camera passes through its target",
        {
            "frames": 3,
            "fps": 1,
            "camera": [
                {"time": 0, "position": [0, 0, 1], "look_at": [0, 0, -1]},
                {"time": 2, "position": [0, 0, -1], "look_at": [0, 0, 1]},
            ],
        },
        r"animation\.camera: frame 1 is not a valid view \(camera at t=1\.0: look_at must differ",
    ),
]


@pytest.mark.parametrize(
    ("section", "message"),
    [pytest.param(s, m, id=name) for name, s, m in BAD_SECTIONS],
)
def test_bad_sections_are_refused(tmp_path, section, message):
    animation = {"frames": 2, **section}
    if animation["frames"] is None:
        del animation["frames"]
    with pytest.raises(SceneError) as info:
        load(tmp_path, animated_scene(animation))
    text = str(info.value)
    assert "\n" not in text, f"not one line: {text!r}"
    assert re.search(message, text), text


def test_duplicate_names_cannot_be_animated(tmp_path):
    data = animated_scene({"frames": 2, "objects": {"cube": [CUBE_KEY]}})
    data["objects"][FLOOR]["name"] = "cube"
    with pytest.raises(SceneError, match="2 objects are named 'cube'"):
        load(tmp_path, data)


@pytest.mark.parametrize(
    "change",
    [
        {"fps": math.nan},
        {"fps": math.inf},
        {"objects": {"cube": [{"time": math.nan}]}},
        {"objects": {"cube": [{"time": math.inf}]}},
        {"objects": {"cube": [{"time": 0, "translate": [0, math.nan, 0]}]}},
        {"objects": {"cube": [{"time": 0, "scale": math.inf}]}},
        {"objects": {"cube": [{"time": 0, "rotation": [1, math.nan, 0, 0]}]}},
        {"camera": [{"time": 0, "position": [math.inf, 0, 0]}]},
        {"camera": [{"time": 0, "vfov_deg": math.nan}]},
    ],
)
def test_non_finite_numbers_are_refused(tmp_path, change):
    """NaN and infinity: refused by the model (and by the JSON reader before it)."""
    section = {"frames": 2, **change}
    with pytest.raises(pydantic.ValidationError, match=r"finite number|greater than|less than"):
        fmt.AnimationSettings.model_validate(section)
    path = tmp_path / "scene.json"
    path.write_text(json.dumps(animated_scene(section)), encoding="utf-8")
    with pytest.raises(SceneError, match=r"non-finite number (NaN|Infinity)"):
        load_scene(path)


def test_quaternions_are_normalised():
    key = fmt.ObjectKeyframe(time=0, rotation=(0, 3e300, 0, 4e300))
    assert key.rotation == (0.0, 0.6, 0.0, 0.8)
    assert fmt.ObjectKeyframe(time=0, rotation=(-2, 0, 0, 0)).rotation == (-1.0, 0.0, 0.0, 0.0)


# --- documentation ----------------------------------------------------------------------------


def doc_json_blocks() -> list[dict]:
    text = (ROOT / "docs" / "scene-format.md").read_text(encoding="utf-8")
    return [json.loads(block) for block in re.findall(r"```json\n(.*?)```", text, re.S)]


def test_documented_animation_example_loads():
    """The docs' animation example, added to the docs' first example (with the cow rigid),
    validates and resolves; it reaches its last keys at its last frame as the docs say."""
    blocks = doc_json_blocks()
    scene, fragment = blocks[0], next(b for b in blocks if "animation" in b)
    scene = copy.deepcopy(scene)
    for obj in scene["objects"]:
        if obj["name"] == "cow":
            obj["kind"] = "rigid"
    model = fmt.SceneFile.model_validate({**scene, **fragment})
    animation = animation_from_file(model)
    assert list(animation.nodes) == [1]
    assert len(animation.nodes[1]) == 3 and len(animation.camera) == 2
    assert (animation.frames - 1) / animation.fps == 2.0 == animation.camera[-1].time

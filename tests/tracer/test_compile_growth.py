"""Loading, checking, compiling and encoding a scene do work linear in its objects: twice the
objects, twice the calls (counted, not timed: ``bench/compile_curve.py`` measures the seconds,
up to 200,000 objects)."""

import json
import math
import sys

import pytest

from tracer.compiled.scene import compile_scene
from tracer.scene.checks import check_state
from tracer.scene.codec import decode_state, encode_state
from tracer.scene.loader import load_scene


def boxes(nodes: int, spacing: int) -> dict:
    """``nodes`` unit boxes on a square grid ``spacing`` apart: 3 bakes them all into one
    static cluster, 2000 gives each its own (farther than 1024 half sizes from any other)."""
    side = math.ceil(math.sqrt(nodes))
    return {
        "materials": {"m": {"type": "diffuse", "reflectance": [0.5, 0.5, 0.5]}},
        "objects": [
            {"shape": {"type": "box", "size": [1, 1, 1]}, "material": "m",
             "transform": {"translate": [spacing * (i % side), 0, spacing * (i // side)]}}
            for i in range(nodes)
        ],
    }  # fmt: skip


def calls(path) -> int:
    """Python and C function calls made by loading, checking, compiling the scene and
    encoding and decoding its snapshot."""
    count = 0

    def profile(frame, event, arg):
        nonlocal count
        if event in ("call", "c_call"):
            count += 1

    sys.setprofile(profile)
    try:
        state = load_scene(path)
        check_state(state)
        compile_scene(state)
        decode_state(encode_state(state))
    finally:
        sys.setprofile(None)
    return count


@pytest.mark.parametrize("spacing", [3, 2000], ids=["one cluster", "a cluster each"])
def test_twice_the_objects_cost_twice_the_calls(tmp_path, spacing):
    compile_scene(load_scene(_write(tmp_path / "warm.json", boxes(16, spacing))))  # kernels
    small = calls(_write(tmp_path / "small.json", boxes(256, spacing)))
    large = calls(_write(tmp_path / "large.json", boxes(1024, spacing)))
    assert large / small < 4.2, (small, large)  # 4x the objects; quadratic work gives 16x


def _write(path, scene: dict):
    path.write_text(json.dumps(scene))
    return path

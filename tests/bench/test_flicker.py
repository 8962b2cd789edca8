"""Smoke test of ``bench/flicker.py``: tiny sequences of the Cornell box, and the properties its
figures rest on (the benchmark itself is run by hand: ``./dev bench flicker``)."""

import importlib.util
import math
import sys
from pathlib import Path

import numpy as np
import pytest

BENCH = Path(__file__).resolve().parents[2] / "bench"


def load_flicker():
    """``bench/flicker.py`` as a module (its ``from common import ...`` needs ``bench/`` on the
    path, after the packages so that ``bench/cluster.py`` shadows nothing)."""
    if str(BENCH) not in sys.path:
        sys.path.append(str(BENCH))
    spec = importlib.util.spec_from_file_location("bench_flicker", BENCH / "flicker.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def flicker():
    return load_flicker()


@pytest.fixture(scope="module")
def rows(flicker):
    args = flicker.parse_args(
        ["--scenes", "cornell-box", "--size", "32x18", "--frames", "3", "--spp", "4",
         "--reference-spp", "64", "--qualities", "fast", "--prefilter", "on", "--degrees", "5",
         "--threads", "2"]
    )  # fmt: skip
    return {(r["camera"], r["sequence"]): r for r in flicker.measure(args)}


def test_the_orbit_keeps_the_distance_and_a_full_turn_comes_back(flicker):
    from tracer.scene.format import Camera

    camera = Camera(position=(1.0, 2.0, 5.0), look_at=(0.0, 1.0, 0.0))
    turned = flicker.orbit(camera, 30.0)
    distance = np.linalg.norm(np.subtract(camera.position, camera.look_at))
    assert np.linalg.norm(np.subtract(turned.position, turned.look_at)) == pytest.approx(distance)
    assert turned.position[1] == pytest.approx(camera.position[1])  # about the up axis
    assert not np.allclose(turned.position, camera.position)
    assert np.allclose(flicker.orbit(camera, 360.0).position, camera.position)


def test_the_still_references_change_less_than_raw_frames(rows):
    noise = rows["still", "reference noise"]["change"]
    raw = rows["still", "raw"]
    assert 0.0 < noise < raw["change"] / 2
    assert rows["still", "denoise"]["change"] < raw["change"]
    # One reference for every still frame: the error's change is the frames' own.
    assert raw["error_flicker"] == pytest.approx(raw["change"])
    assert raw["excess"] == pytest.approx(raw["change"])


def test_the_moving_reference_sees_the_motion(rows):
    reference = rows["moving", "reference"]
    assert reference["change"] > rows["still", "reference noise"]["change"]
    assert 0.0 < reference["error_flicker_noise_removed"] < reference["change"]
    raw = rows["moving", "raw"]
    assert raw["reference_change"] == reference["error_flicker_noise_removed"]
    assert raw["error_flicker_noise_removed"] <= raw["error_flicker"]


def test_the_blends_error_falls_over_frames(rows):
    for sequence in ("blend", "blend, denoise"):
        errors = rows["still", sequence]["rel_mse_frames"]
        assert len(errors) == 3 and all(math.isfinite(e) for e in errors)
        assert errors[-1] < errors[0], (sequence, errors)
    raw = rows["still", "blend"]["rel_mse_frames"]
    assert raw[2] < raw[1] < raw[0]

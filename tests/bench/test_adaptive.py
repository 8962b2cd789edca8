"""Smoke test of ``bench/adaptive.py``: its reading of the time to a target off the waves, and
one tiny frame each way on the Cornell box against a made-up reference (the benchmark itself
is run by hand: ``./dev bench adaptive``)."""

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

from cli.commands.samples import REPO_SCENES
from tracer.accuracy.error_estimate import PARTS
from tracer.compiled.scene import compile_scene
from tracer.render import render_image
from tracer.scene import format as fmt
from tracer.scene.loader import load_scene

BENCH = Path(__file__).resolve().parents[2] / "bench"


@pytest.fixture(scope="module")
def bench():
    """``bench/adaptive.py`` as a module (``bench/`` on the path after the packages)."""
    if str(BENCH) not in sys.path:
        sys.path.append(str(BENCH))
    spec = importlib.util.spec_from_file_location("bench_adaptive", BENCH / "adaptive.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_time_to_reads_the_log_log_line(bench):
    records = [
        {"seconds": 1.0, "mean_spp": 4.0, "rel_mse": 4e-2},
        {"seconds": 4.0, "mean_spp": 16.0, "rel_mse": 1e-2 / 4},
    ]
    # relMSE ~ 1/t^2 on the line through both: 1e-2 at t = 2.
    assert bench.time_to(records, 1e-2) == pytest.approx(2.0)
    assert bench.time_to(records, 1e-2, "mean_spp") == pytest.approx(8.0)
    assert bench.time_to(records, 1e-4) is None
    assert bench.time_to(records[1:], 1e-2) == 4.0  # below it from the first wave on


@pytest.fixture(scope="module")
def tiny_frames(bench):
    """One tiny frame of the Cornell box each way against a made-up reference: per mode, its
    records and its snapshot at the target."""
    state = load_scene(REPO_SCENES / "cornell-box" / "scene.json")
    scene = compile_scene(state)
    camera = fmt.override(scene.camera, width=16, height=12)
    settings = fmt.override(scene.render, spp=64)
    reference = type("Ref", (), {})()
    reference.mean = render_image(scene, camera, settings)[0].astype(np.float64)
    frames = {}
    for mode in bench.MODES:
        snapshot = {}
        records = bench.frame_run(scene, camera, settings, reference, 0.0, mode, 64, 1, snapshot)
        frames[mode] = records, snapshot
    return frames


def test_a_tiny_frame_each_way(bench, tiny_frames):
    for records, snapshot in tiny_frames.values():
        assert records and records[0]["spp"] == PARTS
        assert all(r["mean_spp"] <= r["spp"] for r in records)
        assert [r["seconds"] for r in records] == sorted(r["seconds"] for r in records)
        # The samples-per-pixel map adds up to the samples the parts were rendered with.
        hit = bench.at_target(records)
        spp = snapshot["pixel_spp"]
        assert spp.sum() == hit["samples"] and spp.mean() == pytest.approx(hit["mean_spp"])
    on = tiny_frames["on"][1]["pixel_spp"]
    assert on.min() < on.max()  # the tiny frame did sample adaptively


def test_the_spp_map_figure_is_written(tiny_frames, tmp_path):
    from adaptive_figures import spp_map_figure

    on, off = tiny_frames["on"][1], tiny_frames["off"][1]
    path = spp_map_figure("cornell-box", 1e-2, on, off, tmp_path / "spp.png")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"

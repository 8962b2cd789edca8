"""Interactive sessions: the blend converges to the running mean, camera motion and scene
changes raise it, the workload scaler holds a frame time; end to end through the coordinator."""

import math

import numpy as np
import pytest

from cluster.coordinator import Coordinator
from cluster.scene_graph import SceneGraph
from cluster.session import (
    RESOLUTION_SCALES,
    Convergence,
    InteractiveSession,
    WorkloadScaler,
    camera_motion,
)
from tests.worker.test_replica import CAMERA, studio
from tracer.compiled.scene import compile_scene
from tracer.render import render_image


def test_a_still_view_blends_to_the_running_mean():
    convergence = Convergence(min_blend=0.1)
    assert [convergence.next_blend() for _ in range(5)] == [1.0, 1 / 2, 1 / 3, 1 / 4, 1 / 5]


def test_camera_motion_raises_the_blend_in_proportion():
    convergence = Convergence(min_blend=0.1, full_motion=0.05)
    for _ in range(50):
        convergence.next_blend()
    assert convergence.next_blend(0.05) == 1.0  # a full move starts over
    for _ in range(50):
        convergence.next_blend()
    small = convergence.next_blend(0.0125)  # a quarter of a full move
    assert 0.25 <= small <= 1 / 3
    assert convergence.next_blend() < small  # converging again once the camera stops


def test_a_scene_change_holds_the_floor_then_lets_go():
    convergence = Convergence(min_blend=0.2)
    for _ in range(20):
        convergence.next_blend()
    blends = [convergence.next_blend(scene_changed=True)]
    blends += [convergence.next_blend() for _ in range(8)]
    assert all(b >= 0.2 for b in blends[:5])
    assert blends[-1] < 0.2


@pytest.mark.parametrize("bad", [0.0, -1.0, 1.5])
def test_convergence_refuses_a_bad_floor(bad):
    with pytest.raises(ValueError, match="min_blend"):
        Convergence(min_blend=bad)


def simulate(scaler: WorkloadScaler, seconds_per_sample: float, frames: int = 40) -> list[float]:
    """Frame time proportional to spp x pixels; returns the frame times."""
    times = []
    for _ in range(frames):
        seconds = seconds_per_sample * scaler.spp * scaler.scale**2
        times.append(seconds)
        scaler.update(seconds)
    return times


def test_the_scaler_holds_a_reachable_frame_time():
    scaler = WorkloadScaler(target_seconds=0.1, max_spp=256)
    times = simulate(scaler, seconds_per_sample=0.004)  # 25 spp fit in 0.1 s
    assert scaler.scale == 1.0
    assert abs(times[-1] - 0.1) <= 0.1 * 0.1
    assert 23 <= scaler.spp <= 27


def test_the_scaler_lowers_resolution_when_one_sample_is_too_slow():
    scaler = WorkloadScaler(target_seconds=0.1)
    simulate(scaler, seconds_per_sample=1.0)  # 1 spp at full size takes 10x the target
    assert scaler.scale == RESOLUTION_SCALES[-1]
    assert scaler.spp == 1


def test_the_scaler_restores_resolution_before_adding_samples():
    scaler = WorkloadScaler(target_seconds=0.1)
    simulate(scaler, seconds_per_sample=1.0)
    simulate(scaler, seconds_per_sample=0.01)  # the machine got 100x faster
    assert scaler.scale == 1.0
    assert 8 <= scaler.spp <= 12


def test_camera_motion_measure():
    moved = CAMERA.model_copy(update={"position": (0.5, 3.0, 9.0)})
    bigger = CAMERA.model_copy(update={"width": 64})
    assert camera_motion(CAMERA, CAMERA) == 0.0
    assert 0.0 < camera_motion(CAMERA, moved) < math.inf
    assert camera_motion(CAMERA, bigger) == math.inf


@pytest.fixture(scope="module")
def coordinator():
    graph = SceneGraph(studio())
    with Coordinator(graph, tracers=2) as coordinator:
        yield coordinator


def reference(state, frame: int, camera=CAMERA) -> np.ndarray:
    settings = state.render.model_copy(update={"spp": 1})
    return render_image(compile_scene(state), camera, settings, frame=frame)[0]


def test_a_session_converges_to_the_mean_of_its_frames(coordinator):
    graph = coordinator.graph
    # A frame-rate target no frame misses, and one sample per frame: the workload stays fixed.
    session = InteractiveSession(coordinator, graph, target_fps=1e-3, max_spp=1)
    frames = [session.render_next() for _ in range(3)]
    assert [f.blend for f in frames] == [1.0, 1 / 2, 1 / 3]
    assert all(f.spp == 1 and (f.width, f.height) == (CAMERA.width, CAMERA.height) for f in frames)
    expected = np.mean([reference(graph.state, k) for k in range(3)], axis=0)
    np.testing.assert_allclose(frames[-1].image, expected, rtol=1e-5, atol=1e-7)
    assert frames[-1].samples_accumulated == 3

    moved = CAMERA.model_copy(update={"position": (3.0, 3.0, 7.0)})
    session.set_camera(moved)
    after = session.render_next()
    assert after.blend == 1.0
    assert np.array_equal(after.image, reference(graph.state, 3, moved))

    graph.commit([{"op": "set_transform", "node": "box-a", "transform": {"translate": [0, 2, 0]}}])
    changed = session.render_next()
    assert changed.version == graph.version
    assert changed.blend >= 0.1
    stats = session.stats()
    assert stats["frames"] == 5 and stats["fps"] > 0.0
    session.close()
    with pytest.raises(RuntimeError, match="closed"):
        session.render_next()


def test_a_denoised_session_blends_its_guides_and_denoises_the_blend(coordinator):
    """With denoising on, the shown beauty is bit for bit the plain session's, the guides are
    the running mean of the frames' albedo and normal AOVs, and ``denoised`` denoises the blend;
    turning it off drops the guides."""
    from tracer.render import render_pixels

    graph = coordinator.graph
    plain = InteractiveSession(coordinator, graph, target_fps=1e-3, max_spp=1)
    session = InteractiveSession(coordinator, graph, target_fps=1e-3, max_spp=1)
    with pytest.raises(ValueError, match="denoise must be one of"):
        session.set_denoise("sharp")
    session.set_denoise("fast")
    frames = [session.render_next() for _ in range(3)]
    plain_frames = [plain.render_next() for _ in range(3)]
    assert all(np.array_equal(a.image, b.image) for a, b in zip(frames, plain_frames, strict=True))
    scene = compile_scene(graph.state)
    settings = graph.state.render.model_copy(update={"spp": 1, "aovs": True})
    pixels = CAMERA.width * CAMERA.height
    aovs = [
        render_pixels(scene, 0, pixels, CAMERA, settings, frame=k).aov.reshape(
            CAMERA.height, CAMERA.width, -1
        )
        for k in range(3)
    ]
    mean = np.mean(aovs, axis=0)
    expected = np.concatenate([mean[..., 0:3], mean[..., 3:6]], axis=2)
    last = frames[-1]
    assert last.denoise == "fast" and last.guides.shape == (CAMERA.height, CAMERA.width, 6)
    np.testing.assert_allclose(last.guides, expected, rtol=1e-5, atol=1e-6)
    assert last.prefilter is False  # the studio scene has no texture and no lens
    done = InteractiveSession.denoised(last)
    assert done.guides == ("albedo", "normal") and done.image.shape == last.image.shape
    assert not np.array_equal(done.image, last.image)
    assert session.stats()["denoise"] == "fast"
    session.set_denoise("off")
    off = session.render_next()
    assert off.guides is None and InteractiveSession.denoised(off) is None

    # Guides started in a converged view are their own running mean, not the image's blend.
    session.set_denoise("fast")
    again = [session.render_next() for _ in range(2)]
    later = [
        render_pixels(scene, 0, pixels, CAMERA, settings, frame=k).aov.reshape(
            CAMERA.height, CAMERA.width, -1
        )
        for k in (4, 5)
    ]
    mean = np.mean(later, axis=0)
    expected = np.concatenate([mean[..., 0:3], mean[..., 3:6]], axis=2)
    assert again[-1].blend == pytest.approx(1 / 6)
    np.testing.assert_allclose(again[-1].guides, expected, rtol=1e-5, atol=1e-6)

    # The scene's own render.denoise_prefilter is honoured.
    render = graph.state.render.model_copy(update={"denoise_prefilter": "on"})
    graph.commit([{"op": "set_render", "render": render.model_dump(mode="json")}])
    assert session.render_next().prefilter is True

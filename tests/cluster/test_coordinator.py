"""The coordinator renders through tracer actors exactly what ``render_image`` renders, for any
number of tracers and any balancer, and keeps doing so when tracers are killed, stall, join or
leave, when commits arrive while frames render, and when a Ray node disappears mid-job.

One embedded Ray serves the module (the node-removal test, last, runs its own cluster). Images
are 32x24 at 2 spp: milliseconds per frame, so test-only render delays (``delays`` /
``set_delay``) make tracers slow enough to kill mid-render or to straggle."""

import itertools
import os
import pathlib
import signal
import socket
import threading
import time
from dataclasses import replace

import numpy as np
import pytest
import ray
import trimesh

from cluster.assembler import Assembler
from cluster.balancing import BALANCERS, CostAwareTail, idle_percent
from cluster.connect import connect, disconnect, probe
from cluster.coordinator import Coordinator
from cluster.errors import ClusterError, ClusterUnreachable
from cluster.frame import gap_idle_percent
from cluster.scene_graph import SceneGraph
from cluster.scene_sync import INLINE_COMMITS
from tests.scene_states import translation
from tests.worker.test_replica import CAMERA, studio
from tracer.compiled.scene import compile_scene
from tracer.integrators import aov
from tracer.render import render_image, render_lines, render_pixels
from tracer.request import FrameRequest
from tracer.scene import format as fmt
from tracer.scene.codec import encode_commit, encode_state
from tracer.scene.model import Animation, CameraKey, NodeKey, SceneState
from worker import line_pool
from worker.tracer_actor import UnitsResult
from worker.work_units import WorkUnits

MOVE = {"op": "set_transform", "node": "box-a", "transform": {"translate": [0.5, 1.2, 0.3]}}
CAMERA_MOVE = {
    "op": "set_camera",
    "camera": {**CAMERA.model_dump(), "position": [1.0, 2.5, 8.0]},
}


def reference(state: SceneState, frame: int = 0, sample_start: int = 0) -> np.ndarray:
    """The same frame from one process and one call: tracer.render.render_image."""
    return render_image(compile_scene(state), frame=frame, sample_start=sample_start)[0]


def reference_rays(state: SceneState, frame: int = 0, sample_start: int = 0) -> np.ndarray:
    """Rays traced per line of the same frame in one call (tracer.render.render_lines)."""
    height = state.camera.height
    return render_lines(
        compile_scene(state), 0, height, frame=frame, sample_start=sample_start
    ).rays


def animated(frames: int = 32) -> SceneState:
    """The studio with box-a (rigid) sliding and turning, and the camera dollying in."""
    base = studio()
    quarter = (0.7071067811865476, 0.0, 0.7071067811865476, 0.0)
    animation = Animation(
        fps=8.0,
        frames=frames,
        nodes={
            2: (
                NodeKey(0.0, (-1.5, 0.5, 0.0), (1.0, 0.0, 0.0, 0.0), (1.0, 1.0, 1.0)),
                NodeKey(frames / 8.0, (1.0, 0.9, 1.0), quarter, (0.8, 1.2, 0.8)),
            )
        },
        camera=(
            CameraKey(0.0, (0.0, 3.0, 9.0), (0.0, 0.5, 0.0), (0.0, 1.0, 0.0), 40.0),
            CameraKey(frames / 8.0, (1.5, 2.5, 6.0), (0.0, 0.5, 0.0), (0.0, 1.0, 0.0), 50.0),
        ),
    )
    nodes = dict(base.nodes)
    nodes[2] = type(nodes[2])(2, "box-a", None, translation(-1.5, 0.5, 0), "rigid", "box", "red")
    return SceneState(
        version=0,
        meshes=base.meshes,
        materials=base.materials,
        nodes=nodes,
        camera=base.camera,
        render=base.render,
        sky=base.sky,
        animation=animation,
    )


def animation_references(state: SceneState, frames) -> dict[int, np.ndarray]:
    """Each frame of the animation rendered from scratch after replaying its poses."""
    graph = SceneGraph(state)
    out = {}
    for f in frames:
        graph.frame_commit(f)
        out[f] = reference(graph.state, frame=f)
    return out


def assert_covers(frame) -> None:
    """The accepted ranges partition the frame's units; the split is in order and disjoint, and
    covers the frame unless a dynamic tail handed the rest out in chunks (kind ``tail``, or a
    pool)."""
    height = frame.units.count
    ranges = sorted((r.u0, r.u1) for r in frame.ranges)
    assert ranges[0][0] == 0 and ranges[-1][1] == height
    assert all(a[1] == b[0] for a, b in itertools.pairwise(ranges))
    edges = [(u0, u1) for _, u0, u1 in frame.split]
    assert all(u0 <= u1 for u0, u1 in edges)
    assert all(a[1] <= b[0] for a, b in itertools.pairwise(edges))
    if not frame.pooled and not any(r.kind == "tail" for r in frame.ranges):
        assert edges[0][0] == 0 and edges[-1][1] == height
        assert all(a[1] == b[0] for a, b in itertools.pairwise(edges))


@pytest.fixture
def local_ray(ray_session):
    if not ray.is_initialized():  # the node-removal test replaced it
        connect(num_cpus=2)


_coordinators: dict[int, Coordinator] = {}


@pytest.fixture
def shared(local_ray):
    """A coordinator with N tracers, kept for the tests that ask for the same N (only one is
    alive at a time: they share the 2 CPUs)."""

    def get(n: int) -> Coordinator:
        if n not in _coordinators:
            for other in _coordinators.values():
                other.close()
            _coordinators.clear()
            _coordinators[n] = Coordinator(SceneGraph(studio()), tracers=n)
        return _coordinators[n]

    return get


@pytest.fixture(scope="module", autouse=True)
def _close_shared():
    yield
    for coordinator in _coordinators.values():
        coordinator.close()
    _coordinators.clear()


@pytest.fixture
def fresh(local_ray):
    """Coordinators made by the test, closed after it (and the shared one closed before)."""
    for other in _coordinators.values():
        other.close()
    _coordinators.clear()
    made = []

    def make(*args, **kwargs) -> Coordinator:
        made.append(Coordinator(*args, **kwargs))
        return made[-1]

    yield make
    for coordinator in made:
        coordinator.close()


# --- pixels ---------------------------------------------------------------------------------


CASES = [(n, name) for n in (1, 2, 3) for name in sorted(BALANCERS)]


@pytest.mark.parametrize(("tracers", "balancer"), CASES, ids=[f"{n}-{b}" for n, b in CASES])
def test_frames_equal_render_image(shared, tracers, balancer):
    """Frames at several versions, frame numbers and sample offsets (so the balancer has
    learned and re-split between them) equal render_image bit for bit."""
    coordinator = shared(tracers)
    coordinator.use_balancer(balancer)
    graph = coordinator.graph
    for number, edit, sample_start in [(0, None, 0), (1, MOVE, 0), (7, CAMERA_MOVE, 3)]:
        if edit is not None:
            graph.commit([edit])
        frame = coordinator.render_frame(FrameRequest(number, sample_start=sample_start))
        assert frame.version == graph.version and frame.frame == number
        assert frame.rgb.dtype == np.float32 and frame.rgb.shape == (24, 32, 3)
        assert np.array_equal(frame.rgb, reference(graph.state, number, sample_start))
        assert frame.cost.shape == (24,) and frame.cost.min() > 0
        # Several tracers on 24 lines: each line is cut into 4 spans of 8 pixels.
        assert frame.units == WorkUnits(32, 24, 1 if tracers == 1 else 4)
        assert np.array_equal(frame.units.per_line(frame.unit_cost), frame.cost)
        assert len(frame.split) == tracers
        heads = {t for t, u0, u1 in frame.split if u1 > u0}
        if any(r.kind == "tail" for r in frame.ranges):
            assert {r.tracer for r in frame.ranges} >= heads
        else:
            assert {r.tracer for r in frame.ranges} == heads
        assert_covers(frame)
        assert 0.0 <= frame.idle_percent < 100.0 and frame.wall_seconds > 0.0
        assert (frame.failures, frame.duplicates) == (0, 0)


@pytest.mark.parametrize("tracers", [1, 2])
def test_a_region_of_a_frame_is_those_pixels_of_the_whole_frame(shared, tracers):
    """Whole lines, and a run inside one line, rendered as frames of their own (split among
    the tracers): the same bits as those pixels of the whole frame."""
    coordinator = shared(tracers)
    state = coordinator.graph.state
    whole = reference(state, 3, 1).reshape(-1, 3)
    for r0, r1, view in [(0, 5 * 32, (32, 5)), (5 * 32, 24 * 32, (32, 19)), (227, 253, (26, 1))]:
        frame = coordinator.render_frame(FrameRequest(3, sample_start=1, region=(r0, r1)))
        assert frame.rgb.shape == (view[1], view[0], 3)
        assert np.array_equal(frame.rgb.reshape(-1, 3), whole[r0:r1])
        assert frame.cost.shape == (view[1],) and frame.cost.min() > 0


def test_default_is_one_tracer_per_node_with_all_its_cpus(fresh):
    coordinator = fresh(SceneGraph(studio()))
    (tracer,) = coordinator.tracers()
    assert tracer["state"] == "ready" and tracer["cpus"] == 2.0 and tracer["threads"] == 2
    assert tracer["warm_up"]["cache_misses"] == 0  # loaded from the shared kernel cache
    info = coordinator.info(tracer["id"])
    assert info.threads == 2 and info.node == ray.get_runtime_context().get_node_id()
    assert info.cache_dir == os.environ["NUMBA_CACHE_DIR"]
    _, hits = coordinator.query([[-1.5, 3.5, 0.1]], [[0.0, -1.0, 0.0]])  # picking, on a tracer
    assert hits.material == ["white"] and hits.node[0] == 3


def test_a_commit_never_leaks_into_a_frame_scheduled_before_it(fresh):
    """Frame N is scheduled at version v; a commit (v + 1) lands while it renders and frame
    N + 1 is scheduled after it: N shows v, N + 1 shows v + 1."""
    coordinator = fresh(SceneGraph(studio()), tracers=2, delays=[0.4, 0.4])
    graph = coordinator.graph
    before = graph.state
    job = coordinator.submit_frame(FrameRequest(0))
    time.sleep(0.1)
    graph.commit([MOVE])
    after = graph.state
    later = coordinator.submit_frame(FrameRequest(1))
    first, second = coordinator.wait_frame(job), coordinator.wait_frame(later)
    assert (first.version, second.version) == (before.version, after.version)
    assert np.array_equal(first.rgb, reference(before, 0))
    assert np.array_equal(second.rgb, reference(after, 1))
    assert not np.array_equal(reference(after, 0), first.rgb)  # the commit changes pixels


# --- failures -------------------------------------------------------------------------------


def wait_ready(coordinator: Coordinator, tracer: str, timeout: float = 60.0) -> None:
    deadline = time.monotonic() + timeout
    while tracer not in coordinator.ready:
        assert time.monotonic() < deadline, f"{tracer} did not come back"
        time.sleep(0.1)


@pytest.mark.parametrize("pipeline", [1, 2])
def test_every_frame_of_an_animation_comes_in_order_at_any_pipeline_depth(
    fresh, monkeypatch, pipeline
):
    """render_animation yields every frame, in order, with pipeline 1 (off) and 2; with 2,
    frame N+2 is already submitted when N reaches the caller (Bikker's double buffering)."""
    coordinator = fresh(SceneGraph(animated(5)), tracers=1)
    submitted = []
    submit = coordinator.submit_frame

    def recording(request, *args, **kwargs):
        submitted.append(request.frame)
        return submit(request, *args, **kwargs)

    monkeypatch.setattr(coordinator, "submit_frame", recording)
    seen = []
    for frame in coordinator.render_animation(pipeline=pipeline):
        seen.append(frame.frame)
        ahead = min(frame.frame + pipeline, 4)
        assert submitted[-1] == ahead, (frame.frame, submitted)
    assert seen == [0, 1, 2, 3, 4] and submitted == seen


def animation_killing_t1_after(coordinator: Coordinator, frame: int) -> list:
    """Every frame of the graph's animation, with tracer t1 killed by ray.kill (restart
    allowed) once ``frame`` has arrived."""
    frames = []
    for done in coordinator.render_animation():
        frames.append(done)
        if done.frame == frame:
            ray.kill(coordinator.tracer_handle("t1"), no_restart=False)
    return frames


def test_a_killed_tracer_loses_no_frame_of_an_animation(fresh):
    """ray.kill (restart allowed) of one of two tracers during a 32-frame pipelined
    animation: every frame arrives, each equal to render_image of its pose; the tracer is
    restarted, resynced by snapshot, and renders again."""
    state = animated(32)
    expected = animation_references(state, range(32))
    # Even split, so t1 always has lines; no straggler rule, so only the loss is detected.
    graph = SceneGraph(state)
    coordinator = fresh(graph, tracers=2, balancer="none", straggler_floor=30, delays=[0.1, 0.1])
    victim = coordinator.info("t1")
    frames = animation_killing_t1_after(coordinator, 4)
    assert [f.frame for f in frames] == list(range(32))
    for frame in frames:
        assert np.array_equal(frame.rgb, expected[frame.frame]), frame.frame
    assert coordinator.stats["failures"] == 1
    hit = [f for f in frames if f.failures]  # the frames t1 had calls for when it died
    assert hit and hit[0].frame in (5, 6) and all(f.frame <= 8 for f in hit)
    for frame in hit:
        assert frame.reassigned >= 1 and ("t0", "reassigned") in {
            (r.tracer, r.kind) for r in frame.ranges
        }
        assert "t1" not in {r.tracer for r in frame.ranges}
    wait_ready(coordinator, "t1")
    extra = coordinator.render_frame(FrameRequest(31))
    assert np.array_equal(extra.rgb, expected[31])
    back = [r for r in extra.ranges if r.tracer == "t1"]
    assert back and back[0].pid != victim.pid
    assert coordinator.info("t1").incarnation != victim.incarnation


def test_sigkill_mid_range_is_split_among_survivors(fresh):
    """SIGKILL of a tracer's process while it renders its range: the range goes to the other
    tracers, the frame completes without waiting for the dead one, and the restarted tracer
    gets work from a later frame."""
    graph = SceneGraph(studio())
    coordinator = fresh(graph, tracers=3, cpus_per_tracer=0.5, straggler_floor=30)
    expected = reference(graph.state, 2)
    victim = coordinator.info("t1")
    ray.get(coordinator.tracer_handle("t1").set_delay.remote(20.0))
    job = coordinator.submit_frame(FrameRequest(2))
    time.sleep(0.5)
    os.kill(victim.pid, signal.SIGKILL)
    frame = coordinator.wait_frame(job)
    assert np.array_equal(frame.rgb, expected)
    assert frame.failures >= 1 and frame.reassigned >= 1 and frame.wall_seconds < 15.0
    assert {r.tracer for r in frame.ranges} == {"t0", "t2"}
    assert {r.kind for r in frame.ranges} >= {"split", "reassigned"}
    wait_ready(coordinator, "t1")
    again = coordinator.render_frame(FrameRequest(3))
    assert np.array_equal(again.rgb, reference(graph.state, 3))
    assert any(r.tracer == "t1" and r.pid != victim.pid for r in again.ranges)


def test_a_straggler_is_duplicated_and_its_late_answer_discarded(fresh):
    """One tracer stalls (test-only delay): once the other is idle and the range has run
    longer than 2x its prediction plus the floor, an idle tracer renders a copy and the frame
    completes; the straggler's late result is discarded."""
    graph = SceneGraph(studio())
    coordinator = fresh(graph, tracers=2, balancer="none", straggler_floor=0.3)
    handle = coordinator.tracer_handle("t1")
    ray.get(handle.set_delay.remote(2.5))
    start = time.perf_counter()
    frame = coordinator.render_frame(FrameRequest(0))
    assert time.perf_counter() - start < 2.0
    assert np.array_equal(frame.rgb, reference(graph.state, 0))
    assert frame.duplicates == 1 and frame.failures == 0
    assert {(r.tracer, r.kind) for r in frame.ranges} == {("t0", "split"), ("t0", "duplicate")}
    ray.get(handle.set_delay.remote(0.0))  # runs after the straggling render finished
    following = coordinator.render_frame(FrameRequest(1))
    assert coordinator.stats["stale_discarded"] >= 1
    assert np.array_equal(following.rgb, reference(graph.state, 1))


def always_tail() -> CostAwareTail:
    """cost-aware-tail with half of every frame as its tail, in chunks as small as one line,
    whatever the frame's size (the defaults use no tail on these tiny, fast frames)."""
    return CostAwareTail(fraction=0.5, min_chunk=0.0, min_seconds=0.0, min_lines=1)


TRANSPORTS = [True, False]
TRANSPORT_IDS = ["pool", "calls"]


@pytest.mark.parametrize("pooled", TRANSPORTS, ids=TRANSPORT_IDS)
@pytest.mark.parametrize("tracers", [2, 3])
def test_frames_with_a_dynamic_tail_equal_render_image(shared, tracers, pooled):
    """Heads and chunks from 2 and 3 tracers, the tail claimed from a shared line pool or
    handed out in calls of its own: frames at several versions and frame numbers equal
    render_image bit for bit, chunks included."""
    coordinator = shared(tracers)
    coordinator.balancer = always_tail()
    coordinator.line_pool = pooled
    graph = coordinator.graph
    try:
        for number, edit, sample_start in [(0, None, 0), (1, MOVE, 0), (7, CAMERA_MOVE, 3)]:
            if edit is not None:
                graph.commit([edit])
            frame = coordinator.render_frame(FrameRequest(number, sample_start=sample_start))
            assert np.array_equal(frame.rgb, reference(graph.state, number, sample_start))
            assert np.array_equal(frame.rays, reference_rays(graph.state, number, sample_start))
            assert_covers(frame)
            assert frame.pooled == pooled
            kinds = [r.kind for r in frame.ranges]
            heads = sum(u1 > u0 for _, u0, u1 in frame.split)  # a slow tracer may get none
            assert kinds.count("split") == heads, kinds
            if pooled:  # one call per tracer; whoever is free claims the chunks
                assert kinds.count("tail") >= 2 and frame.calls <= tracers, kinds
            else:
                assert kinds.count("tail") >= tracers, kinds
                assert frame.calls == len(frame.ranges) > tracers
    finally:
        coordinator.use_balancer("cost-aware")
        coordinator.line_pool = True


@pytest.mark.parametrize("pooled", TRANSPORTS, ids=TRANSPORT_IDS)
def test_aovs_travel_with_the_frame_bit_for_bit(shared, pooled):
    """A frame that asks for AOVs, split over 2 tracers with a dynamic tail (pooled or in
    calls), and a region of it: the beauty and AOVs are render_pixels' in one call."""
    coordinator = shared(2)
    coordinator.balancer = always_tail()
    coordinator.line_pool = pooled
    state = coordinator.graph.state
    settings = fmt.override(state.render, aovs=True)
    compiled = compile_scene(state)
    width, height = state.camera.width, state.camera.height
    whole = render_pixels(compiled, 0, width * height, state.camera, settings, 2, 1)
    try:
        frame = coordinator.render_frame(FrameRequest(2, settings=settings, sample_start=1))
        assert np.array_equal(frame.rgb.reshape(-1, 3), whole.rgb)
        assert frame.aov.shape == (height, width, aov.CHANNELS)
        assert np.array_equal(frame.aov.reshape(-1, aov.CHANNELS), whole.aov)
        assert any(r.kind == "tail" for r in frame.ranges)
        region = coordinator.render_frame(
            FrameRequest(2, settings=settings, sample_start=1, region=(227, 253))
        )
        assert np.array_equal(region.aov.reshape(-1, aov.CHANNELS), whole.aov[227:253])
        plain = coordinator.render_frame(FrameRequest(2, sample_start=1))
        assert plain.aov is None and np.array_equal(plain.rgb, frame.rgb)
    finally:
        coordinator.use_balancer("cost-aware")
        coordinator.line_pool = True


@pytest.mark.parametrize("pooled", TRANSPORTS, ids=TRANSPORT_IDS)
@pytest.mark.parametrize("tracers", [1, 2, 3])
def test_sample_counts_per_pixel_travel_bit_for_bit(shared, tracers, pooled):
    """A part of an adaptive wave (a sample count per pixel, ``cluster.adaptive``) over 1-3
    tracers with a dynamic tail (pooled or in calls), and a region of it: the pixels
    render_pixels gives in one call."""
    coordinator = shared(tracers)
    coordinator.balancer = always_tail()
    coordinator.line_pool = pooled
    state = coordinator.graph.state
    settings = fmt.override(state.render, spp=4)
    width, height = state.camera.width, state.camera.height
    counts = (np.arange(width * height) * 7 % 4 + 1).astype(np.int32)
    compiled = compile_scene(state)
    whole = render_pixels(compiled, 0, width * height, state.camera, settings, 2, 1, counts=counts)
    try:
        request = FrameRequest(2, settings=settings, sample_start=1, counts=counts)
        frame = coordinator.render_frame(request)
        assert np.array_equal(frame.rgb.reshape(-1, 3), whole.rgb)
        region = coordinator.render_frame(replace(request, region=(227, 253)))
        assert np.array_equal(region.rgb.reshape(-1, 3), whole.rgb[227:253])
    finally:
        coordinator.use_balancer("cost-aware")
        coordinator.line_pool = True


@pytest.mark.parametrize("pooled", TRANSPORTS, ids=TRANSPORT_IDS)
def test_the_dynamic_tail_survives_a_kill_in_a_pipelined_animation(fresh, pooled):
    """A dynamic tail with two tracers through a pipelined 16-frame animation: the frames use
    chunks of the tail (from the pool, or in more calls than tracers), a tracer killed mid-job
    loses no frame, every frame equals render_image of its pose, and the restarted tracer
    takes work again."""
    state = animated(16)
    expected = animation_references(state, range(16))
    graph = SceneGraph(state)
    coordinator = fresh(graph, tracers=2, straggler_floor=30, delays=[0.03, 0.03], line_pool=pooled)
    coordinator.balancer = always_tail()
    frames = animation_killing_t1_after(coordinator, 4)
    assert [f.frame for f in frames] == list(range(16))
    for frame in frames:
        assert np.array_equal(frame.rgb, expected[frame.frame]), frame.frame
        assert_covers(frame)
    assert coordinator.stats["failures"] == 1
    assert any(
        (f.calls <= 2 if pooled else f.calls > 2)
        and f.pooled == pooled
        and "tail" in {r.kind for r in f.ranges}
        for f in frames[:4]
    )
    assert all(0.0 <= f.idle_percent < 100.0 and 0.0 <= f.span_idle_percent < 100 for f in frames)
    wait_ready(coordinator, "t1")
    extra = coordinator.render_frame(FrameRequest(15))
    assert np.array_equal(extra.rgb, expected[15])
    assert "t1" in {r.tracer for r in extra.ranges}


@pytest.mark.parametrize("pooled", TRANSPORTS, ids=TRANSPORT_IDS)
def test_the_dynamic_tail_duplicates_a_straggler(fresh, pooled):
    """With a dynamic tail, a stalled tracer's head and queued chunk are copied to the idle
    one once the tail is used up; the frame completes long before the stall ends."""
    graph = SceneGraph(studio())
    coordinator = fresh(graph, tracers=2, straggler_floor=0.3, line_pool=pooled)
    coordinator.balancer = always_tail()
    ray.get(coordinator.tracer_handle("t1").set_delay.remote(2.5))
    start = time.perf_counter()
    frame = coordinator.render_frame(FrameRequest(0))
    assert time.perf_counter() - start < 2.0
    assert np.array_equal(frame.rgb, reference(graph.state, 0))
    assert frame.duplicates >= 1 and frame.failures == 0
    assert {r.tracer for r in frame.ranges} == {"t0"}
    assert {r.kind for r in frame.ranges} >= {"split", "tail", "duplicate"}
    fast, slow = coordinator.balancer.speeds(["t0", "t1"])  # the stall is learnt (lower bound)
    assert slow < 0.5 * fast, (fast, slow)


def claimed_by_t1(job, chunks: int = 2) -> list[tuple[int, int]]:
    """Claim ``chunks`` of ``job``'s line pool as t1 (owner 1) would, from this process."""
    assert job.pool is not None
    return [job.pool.claim(1) for _ in range(chunks)]


def test_pool_chunks_a_lost_tracer_held_are_reassigned(fresh):
    """A tracer killed after claiming chunks of the pool (claimed here in its name while its
    call sleeps): its range and those chunks go to the survivor, and the frame completes
    without waiting for the restart."""
    graph = SceneGraph(studio())
    # t0 starts late enough for this process to claim first; t1 never starts.
    coordinator = fresh(graph, tracers=2, straggler_floor=30, delays=[0.5, 20.0])
    coordinator.balancer = always_tail()
    victim = coordinator.info("t1")
    job = coordinator.submit_frame(FrameRequest(4))
    held = claimed_by_t1(job)
    time.sleep(0.3)
    os.kill(victim.pid, signal.SIGKILL)
    frame = coordinator.wait_frame(job)
    assert frame.pooled and np.array_equal(frame.rgb, reference(graph.state, 4))
    assert frame.failures == 1 and frame.wall_seconds < 15.0
    assert {r.tracer for r in frame.ranges} == {"t0"}
    reassigned = [(r.u0, r.u1) for r in frame.ranges if r.kind == "reassigned"]
    for u0, u1 in held:  # every held line came back as a reassigned range
        assert all(any(a <= y < b for a, b in reassigned) for y in range(u0, u1)), held


def test_pool_chunks_a_straggler_holds_are_duplicated(fresh):
    """A stalled tracer that holds chunks of the pool: its range and the chunks are copied to
    the idle tracer once the pool is empty; the frame completes long before the stall ends."""
    graph = SceneGraph(studio())
    coordinator = fresh(graph, tracers=2, straggler_floor=0.3, delays=[0.2, 2.5])
    coordinator.balancer = always_tail()
    start = time.perf_counter()
    job = coordinator.submit_frame(FrameRequest(0))
    held = claimed_by_t1(job)
    frame = coordinator.wait_frame(job)
    assert time.perf_counter() - start < 2.0
    assert frame.pooled and np.array_equal(frame.rgb, reference(graph.state, 0))
    assert frame.duplicates == 1 and frame.failures == 0
    copies = [(r.u0, r.u1) for r in frame.ranges if r.kind == "duplicate"]
    for u0, u1 in held:
        assert all(any(a <= y < b for a, b in copies) for y in range(u0, u1)), held


def pool_files() -> set[str]:
    """Line pools this process created that are still on disk."""
    directory = line_pool._directory()
    return {p.name for p in directory.glob(f"{line_pool.PREFIX}-{os.getpid()}-*")}


def test_long_pooled_frames_are_not_taken_for_stragglers(fresh):
    """Frames of about a second (both tracers sleep 1 s first) whose tail is half the frame in
    one-line chunks: the tracer still finishing its last chunk when the other returns is not
    a straggler (pooled calls end together), so nothing is copied; no pool is left behind."""
    graph = SceneGraph(studio())
    coordinator = fresh(graph, tracers=2, straggler_floor=0.3, delays=[1.0, 1.0])
    coordinator.balancer = always_tail()
    for number in range(2):
        frame = coordinator.render_frame(FrameRequest(number))
        assert frame.pooled and frame.duplicates == 0
        assert np.array_equal(frame.rgb, reference(graph.state, number))
    assert not pool_files()


def test_chunks_of_a_pool_the_tracers_cannot_open_are_handed_out_in_calls(fresh, monkeypatch):
    """Tracers that cannot open the frame's pool (here: given a path that does not exist)
    render their heads and say so; the coordinator hands the chunks out itself, the frame
    equals render_image, and the next frame puts its tail in the actor pool instead of a
    file."""
    graph = SceneGraph(studio())
    coordinator = fresh(graph, tracers=2)
    coordinator.balancer = always_tail()
    opened = []
    open_pool = coordinator._frames._open_pool

    def hidden(job, local):
        open_pool(job, local)
        opened.append(job.pool.path)
        job.pool.path += "-elsewhere"  # what the tracers are told

    monkeypatch.setattr(coordinator._frames, "_open_pool", hidden)
    try:
        frame = coordinator.render_frame(FrameRequest(3))
    finally:
        for path in opened:
            pathlib.Path(path).unlink(missing_ok=True)
    assert frame.pooled and np.array_equal(frame.rgb, reference(graph.state, 3))
    kinds = {r.kind for r in frame.ranges}
    assert "reassigned" in kinds and "tail" not in kinds, kinds
    assert_covers(frame)
    monkeypatch.undo()
    after = coordinator.render_frame(FrameRequest(4))
    assert after.pooled and np.array_equal(after.rgb, reference(graph.state, 4))
    assert coordinator._pools.tables is not None  # the actor pool: no file for them
    assert "tail" in {r.kind for r in after.ranges}


def test_a_frame_given_up_leaves_no_pool_behind(fresh):
    """A frame that fails (no answer within the stall timeout) raises ClusterError and
    removes its line pool; so does closing the coordinator with a frame in flight."""
    graph = SceneGraph(studio())
    coordinator = fresh(graph, tracers=2, stall_timeout=0.5, delays=[3.0, 3.0])
    coordinator.balancer = always_tail()
    job = coordinator.submit_frame(FrameRequest(0))
    assert job.pool is not None and pool_files()
    with pytest.raises(ClusterError, match="no tracer answered"):
        coordinator.wait_frame(job)
    assert not pool_files()
    job = coordinator.submit_frame(FrameRequest(1))
    assert pool_files()
    coordinator.close()
    assert not pool_files()
    assert job.pool.claimed() == [] and job.pool.claim(0) is None  # reads after close


def test_gap_idle_percent_counts_waits_between_ranges():
    """One range per tracer: Table 16's measure of the busy seconds. Several: a tracer's gaps
    between results (arrival minus previous arrival minus busy) count as idle."""
    single = {"a": [(1.0, 0.8)], "b": [(1.2, 0.6)]}
    assert gap_idle_percent(single) == pytest.approx(idle_percent([0.8, 0.6]))
    # b: 0.5 s, then a result 0.5 s later that took 0.3 s: a 0.2 s wait -> window 1.0 s
    several = {"a": [(1.0, 1.0)], "b": [(0.5, 0.5), (1.0, 0.3)]}
    assert gap_idle_percent(several) == pytest.approx(100 * (0 + (1.0 - 0.8)) / (2 * 1.0))
    assert gap_idle_percent({}) == 0.0


def test_tracers_join_and_leave_between_frames(fresh):
    graph = SceneGraph(studio())
    coordinator = fresh(graph, tracers=1, cpus_per_tracer=1)
    first = coordinator.render_frame(FrameRequest(0))
    assert [t for t, _, _ in first.split] == ["t0"]
    assert coordinator.add_tracers(1) == ["t1"]
    graph.commit([MOVE])
    second = coordinator.render_frame(FrameRequest(1))
    assert [t for t, _, _ in second.split] == ["t0", "t1"]
    assert {r.tracer for r in second.ranges} == {"t0", "t1"}
    coordinator.remove_tracer("t0")
    third = coordinator.render_frame(FrameRequest(2))
    assert [t for t, _, _ in third.split] == ["t1"]
    for frame, number in [(first, 0), (second, 1), (third, 2)]:
        assert np.array_equal(frame.rgb, reference(graph.state if number else studio(), number))


def test_tracers_behind_the_log_or_reset_are_resynced(fresh):
    """A log too short to catch up (log_limit=1) means a snapshot; a tracer whose replica went
    back behind the coordinator's back answers OutOfSync and is resent what it needs."""
    graph = SceneGraph(studio(), log_limit=1)
    coordinator = fresh(graph, tracers=2)
    coordinator.render_frame(FrameRequest(0))
    for edit in (MOVE, CAMERA_MOVE, {"op": "set_sky", "radiance": [0.2, 0.3, 0.4]}):
        graph.commit([edit])
    frame = coordinator.render_frame(FrameRequest(1))
    assert np.array_equal(frame.rgb, reference(graph.state, 1))
    ray.get(coordinator.tracer_handle("t0").sync_snapshot.remote(encode_state(studio()), graph.key))
    frame = coordinator.render_frame(FrameRequest(2))
    assert frame.resyncs >= 1
    assert np.array_equal(frame.rgb, reference(graph.state, 2))
    assert all(t["synced"] == graph.version for t in coordinator.tracers())


def test_graphs_taking_turns_keep_their_replicas_and_their_pixels(fresh):
    """Frames of two graphs in turns through one coordinator: each equals its own reference,
    and once every tracer holds both, a turn sends neither a snapshot nor a resync. Commits
    to one graph reach its replicas as commit buffers; the other is untouched."""
    own, other = SceneGraph(studio()), SceneGraph(studio())
    other.commit([CAMERA_MOVE])
    coordinator = fresh(own, tracers=2)
    for number in range(4):
        graph = (own, other)[number % 2]
        if number == 2:
            own.commit([MOVE])
        frame = coordinator.render_frame(FrameRequest(number), graph=graph)
        assert frame.version == graph.version
        assert np.array_equal(frame.rgb, reference(graph.state, number)), number
        if number >= 2:
            assert frame.resyncs == 0
    snapshots = {key for key, _ in coordinator._sync._snapshots}
    assert snapshots == {own.key, other.key}
    assert all(len(coordinator.info(t).scenes) == 2 for t in coordinator.ready)


def test_a_query_sees_the_graph_at_its_current_version(fresh):
    """``query`` on a given graph answers at that graph's current version, commits included,
    whatever the tracers rendered last."""
    own, other = SceneGraph(studio()), SceneGraph(studio())
    coordinator = fresh(own, tracers=1)
    down = ([[0.5, 3.5, 0.3]], [[0.0, -1.0, 0.0]])
    version, before = coordinator.query(*down, graph=other)
    other.commit([MOVE])
    coordinator.render_frame(FrameRequest(0))  # the tracer last touched another graph
    version_after, after = coordinator.query(*down, graph=other)
    assert (version, version_after) == (0, 1)
    assert after.t[0] < before.t[0]
    _, own_hits = coordinator.query(*down)
    assert own_hits.t[0] == before.t[0]


def test_large_commit_buffers_go_through_the_object_store(fresh):
    """A commit buffer over INLINE_COMMITS bytes is put once and shared by reference."""
    graph = SceneGraph(studio())
    coordinator = fresh(graph, tracers=2)
    coordinator.render_frame(FrameRequest(0))
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=0.6)
    op = {"op": "replace_mesh", "mesh": "blob", "vertices": sphere.vertices, "faces": sphere.faces}
    commit = graph.commit([op])
    assert len(encode_commit(commit)) > INLINE_COMMITS
    frame = coordinator.render_frame(FrameRequest(1))
    assert np.array_equal(frame.rgb, reference(graph.state, 1))
    assert list(coordinator._sync._buffers) == [(graph.key, 0, 1)]  # one put for both tracers


def test_the_assembler_takes_only_what_it_assigned():
    """Results of another frame, version, range or unit layout, or of the wrong shape, are
    refused; units delivered twice are written once (the first delivery wins), also where a
    copy overlaps two ranges."""
    units = WorkUnits(4, 3, 2)  # 3 lines of 4 pixels, 6 units of 2 pixels
    assembler = Assembler(frame=3, version=7, units=units)
    for u0, u1 in [(0, 4), (4, 6), (3, 5)]:
        assembler.assign(u0, u1)

    def result(frame=3, version=7, u0=0, u1=4, value=1.0, spans=2):
        rgb = np.full((2 * (u1 - u0), 3), value, np.float32)
        cost = np.arange(u0, u1, dtype=np.int64) + 1
        return UnitsResult(
            "t", frame, version, u0, u1, rgb, cost, 0.1, 0.0, 1, "n", "i", spans=spans
        )

    stale = [result(frame=2), result(version=6), result(u0=1), result(u1=3), result(spans=1)]
    for refused in stale:
        assert assembler.accept(refused) == -1
    bad = result()
    bad.rgb = bad.rgb[:-1]
    assert assembler.accept(bad) == -1
    assert assembler.rejected == 6 and not assembler.done.any()
    assert assembler.accept(result()) == 4
    assert assembler.accept(result(value=5.0)) == 0  # already written: first one wins
    assert assembler.missing() == [(4, 6)] and not assembler.complete
    assert assembler.accept(result(u0=3, u1=5, value=5.0)) == 1  # only unit 4 is new
    assert assembler.accept(result(u0=4, u1=6, value=2.0)) == 1
    pixels = assembler.rgb.reshape(-1, 3)[:, 0]
    assert assembler.complete and list(pixels) == [1.0] * 8 + [5.0] * 2 + [2.0] * 2
    assert list(assembler.cost) == [1, 2, 3, 4, 5, 6]
    assert list(assembler.line_cost()) == [3, 7, 11]


def test_an_unknown_balancer_is_refused_before_any_tracer_starts(local_ray):
    with pytest.raises(ValueError, match="robin-hood"):
        Coordinator(SceneGraph(studio()), balancer="fastest")


def test_unreachable_addresses_fail_fast(local_ray):
    """A closed port, a bad address and a server that is not Ray: ClusterUnreachable within
    seconds, even though this process is already connected to a Ray."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        closed = s.getsockname()[1]
    start = time.monotonic()
    with pytest.raises(ClusterUnreachable, match="refused"):
        connect(f"127.0.0.1:{closed}")
    with pytest.raises(ClusterUnreachable, match="not a Ray address"):
        connect("no-port-here")
    server = socket.create_server(("127.0.0.1", 0))

    def answer_http() -> None:
        conn, _ = server.accept()
        with conn:
            conn.recv(1024)
            conn.sendall(b"HTTP/1.1 400 Bad Request\r\n\r\n")

    thread = threading.Thread(target=answer_http, daemon=True)
    thread.start()
    with server, pytest.raises(ClusterUnreachable, match="not Ray"):
        probe(f"127.0.0.1:{server.getsockname()[1]}")
    thread.join(5)
    probe(ray.get_runtime_context().gcs_address)  # the real thing answers
    assert time.monotonic() - start < 10.0


# --- a node disappears ----------------------------------------------------------------------


@pytest.fixture
def headless_cluster():
    """A ``ray.cluster_utils.Cluster`` whose head has no CPUs (the test adds worker nodes and
    connects), in place of the module's embedded Ray; shut down afterwards."""
    from ray.cluster_utils import Cluster

    for other in _coordinators.values():
        other.close()
    _coordinators.clear()
    disconnect()
    cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": 0})
    yield cluster
    disconnect()
    cluster.shutdown()


def test_a_node_removed_mid_animation_does_not_stop_the_job(headless_cluster):
    """A head without CPUs and two worker nodes of one CPU, one tracer each, the tail in the
    actor pool (``cost-aware-tail``); one worker node is removed while the animation renders.
    Every frame arrives, equal to render_image; the lost tracer cannot be restarted (no free
    CPU) and the job goes on without it."""
    state = animated(16)
    expected = animation_references(state, range(16))
    cluster = headless_cluster
    coordinator = None
    try:
        workers = [cluster.add_node(num_cpus=1) for _ in range(2)]
        cluster.wait_for_nodes()
        connect(cluster.address)
        coordinator = Coordinator(
            SceneGraph(state), balancer="cost-aware-tail", straggler_floor=30, delays=[0.05, 0.05]
        )
        tracers = coordinator.tracers()
        assert [t["cpus"] for t in tracers] == [1.0, 1.0]
        nodes = {coordinator.info(t["id"]).node for t in tracers}
        assert nodes == {w.node_id for w in workers}
        doomed = next(w for w in workers if w.node_id == coordinator.info("t1").node)
        frames = []
        for frame in coordinator.render_animation():
            frames.append(frame)
            if frame.frame == 3:
                cluster.remove_node(doomed)
        assert [f.frame for f in frames] == list(range(16))
        for frame in frames:
            assert np.array_equal(frame.rgb, expected[frame.frame]), frame.frame
        # Tracers on two nodes: the tail went to the actor pool, both claimed from it.
        assert coordinator._pools.tables is not None and frames[0].pooled
        assert {r.tracer for r in frames[0].ranges if r.kind == "tail"} == {"t0", "t1"}
        assert coordinator.stats["failures"] >= 1 and coordinator.stats["reassigned"] >= 1
        assert {r.tracer for f in frames[8:] for r in f.ranges} == {"t0"}
        assert coordinator.tracers()[1]["state"] in ("recovering", "dead")  # nowhere to go
    finally:
        if coordinator is not None:
            coordinator.close()


def test_a_lost_pool_actor_costs_no_frame_and_no_tracer(headless_cluster):
    """Tracers on two nodes pool their tail in the actor pool (``cost-aware-tail``); the
    pool actor is killed between frames and again mid-frame: every frame still equals
    render_image, no tracer is taken for lost, and the next frame gets a new pool actor."""
    graph = SceneGraph(studio())
    cluster = headless_cluster
    coordinator = None
    try:
        for _ in range(2):
            cluster.add_node(num_cpus=1)
        cluster.wait_for_nodes()
        connect(cluster.address)
        coordinator = Coordinator(
            graph, balancer="cost-aware-tail", straggler_floor=30, delays=[0.05, 0.05]
        )
        frames = [coordinator.render_frame(FrameRequest(0))]
        ray.kill(coordinator._pools.tables)  # between frames: the next one finds it dead
        frames.append(coordinator.render_frame(FrameRequest(1)))
        job = coordinator.submit_frame(FrameRequest(2))
        time.sleep(0.02)  # mid-frame, while the tracers render their heads
        if coordinator._pools.tables is not None:
            ray.kill(coordinator._pools.tables)
        frames.append(coordinator.wait_frame(job))
        frames += [coordinator.render_frame(FrameRequest(k)) for k in (3, 4)]
        for frame in frames:
            assert np.array_equal(frame.rgb, reference(graph.state, frame.frame)), frame.frame
        assert coordinator.stats["failures"] == 0
        assert ray.get(coordinator._pools.tables.rows.remote(-1), timeout=10) == []  # a new one
        assert frames[-1].pooled and "tail" in {r.kind for r in frames[-1].ranges}
    finally:
        if coordinator is not None:
            coordinator.close()


def wait_until_dead(node_id: str, timeout: float = 120.0) -> None:
    """Wait until Ray no longer lists ``node_id`` as alive."""
    deadline = time.monotonic() + timeout
    while any(n["NodeID"] == node_id and n["Alive"] for n in ray.nodes()):
        assert time.monotonic() < deadline, f"Ray still lists node {node_id} as alive"
        time.sleep(0.2)


def test_a_node_that_joins_gets_a_tracer_from_the_next_frame(headless_cluster):
    """One tracer per node (the default) on a head without CPUs and one worker; a second
    worker joins, ``place_new_nodes`` starts a tracer there (once: a second call finds no new
    node), warmed up before it is ready, and the next frames are shared by both, equal to
    render_image. The second worker leaves and a third joins: the lost tracer is retired
    rather than left to come back beside the new one. A tracer removed on purpose is not
    placed again."""
    state = animated(4)
    expected = animation_references(state, range(4))
    cluster = headless_cluster
    coordinator = None
    try:
        first = cluster.add_node(num_cpus=1)
        cluster.wait_for_nodes()
        connect(cluster.address)
        coordinator = Coordinator(SceneGraph(state), straggler_floor=30)
        assert coordinator.place_new_nodes() == []
        frames = list(coordinator.render_animation(frames=[0]))
        assert {r.tracer for r in frames[0].ranges} == {"t0"}
        second = cluster.add_node(num_cpus=1)
        cluster.wait_for_nodes()
        assert coordinator.place_new_nodes() == ["t1"]
        assert coordinator.place_new_nodes() == []  # it is starting there already
        deadline = time.monotonic() + 120
        while "t1" not in coordinator.ready and time.monotonic() < deadline:
            time.sleep(0.1)
        t1 = next(t for t in coordinator.tracers() if t["id"] == "t1")
        assert t1["warm_up"] is not None and t1["node"] == second.node_id != first.node_id
        frames += list(coordinator.render_animation(frames=[1, 2]))
        assert {r.tracer for r in frames[-1].ranges} == {"t0", "t1"}
        cluster.remove_node(second)
        third = cluster.add_node(num_cpus=1)
        cluster.wait_for_nodes()
        frames += list(coordinator.render_animation(frames=[3]))  # t1 is lost in or before it
        wait_until_dead(second.node_id)  # Ray's health checks take longer on a loaded machine
        assert coordinator.place_new_nodes() == ["t2"]
        assert {t["id"]: t["state"] for t in coordinator.tracers()}["t1"] == "retired"
        deadline = time.monotonic() + 120
        while "t2" not in coordinator.ready and time.monotonic() < deadline:
            time.sleep(0.1)
        assert coordinator.info("t2").node == third.node_id
        frames += list(coordinator.render_animation(frames=[0]))
        assert {r.tracer for r in frames[-1].ranges} == {"t0", "t2"}
        coordinator.remove_tracer("t2")
        assert coordinator.place_new_nodes() == []  # removed on purpose: its node is declined
        for frame in frames:
            assert np.array_equal(frame.rgb, expected[frame.frame]), frame.frame
    finally:
        if coordinator is not None:
            coordinator.close()

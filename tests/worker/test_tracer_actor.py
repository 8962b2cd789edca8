"""The tracer: in-process it renders what ``render_image`` renders, at exactly the version asked
for, from a snapshot plus commit buffers, and says when it cannot; as a Ray actor it gets its
snapshot through the object store, warm-starts from the shared kernel cache, and comes back
empty (and says so) after Ray restarts its process."""

import os
import time

import numpy as np
import pytest
import ray

from cluster.scene_graph import SceneGraph
from tests.worker.test_replica import studio
from tracer.compiled.scene import compile_scene
from tracer.render import render_image
from tracer.request import FrameRequest
from tracer.scene.codec import encode_commit, encode_state
from worker.envelope import DEFAULT_SCENE, SceneEnvelope
from worker.line_pool import LinePool
from worker.tracer_actor import MAX_SCENES, OutOfSync, Tracer, UnitsResult, remote_tracer
from worker.work_units import WorkUnits

MOVE = {"op": "set_transform", "node": "box-a", "transform": {"translate": [0.5, 1.2, 0.3]}}
SKY = {"op": "set_sky", "radiance": [0.3, 0.2, 0.1]}


def reference(state, frame=0, sample_start=0) -> np.ndarray:
    return render_image(compile_scene(state), frame=frame, sample_start=sample_start)[0]


def rendered(
    tracer,
    version,
    commits=(),
    frame=0,
    ranges=None,
    spans=1,
    sample_start=0,
    snapshot=None,
    scene=DEFAULT_SCENE,
) -> np.ndarray:
    """The frame assembled from ``tracer.render`` calls over unit ``ranges`` (default one
    call), ``spans`` units per line."""
    camera = studio().camera
    units = WorkUnits(camera.width, camera.height, spans)
    parts = []
    for u0, u1 in ranges or [(0, units.count)]:
        envelope = SceneEnvelope(scene, version, list(commits), snapshot)
        request = FrameRequest(frame, sample_start=sample_start, units=(u0, u1))
        out = tracer.render(envelope, request, spans=spans)
        assert isinstance(out, UnitsResult), out
        assert (out.frame, out.version, out.u0, out.u1, out.spans) == (
            frame,
            version,
            u0,
            u1,
            spans,
        )
        p0, p1 = units.pixels(u0, u1)
        assert out.rgb.dtype == np.float32 and out.cost.dtype == np.int64
        assert out.rgb.shape == (p1 - p0, 3) and out.cost.shape == (u1 - u0,)
        assert out.rays.shape == (u1 - u0,) and np.all(out.rays >= units.sizes(u0, u1))
        parts.append(out.rgb)
    return np.concatenate(parts).reshape(camera.height, camera.width, 3)


# --- the plain class ------------------------------------------------------------------------


def test_tracer_renders_like_render_image():
    """Any split of the lines, any thread count: the pixels of render_image, bit for bit."""
    state = studio()
    tracer = Tracer("t", cpus=2)
    assert tracer.threads == 2 and tracer.version() is None
    assert tracer.sync_snapshot(encode_state(state)) == 0
    expected = reference(state, frame=5, sample_start=3)
    assert np.array_equal(rendered(tracer, 0, frame=5, sample_start=3), expected)
    one = Tracer("u", cpus=0.5)  # a fractional CPU still renders, on one thread
    assert one.threads == 1
    one.sync_snapshot(encode_state(state))
    split = [(0, 7), (7, 8), (8, 24)]
    assert np.array_equal(rendered(one, 0, frame=5, ranges=split, sample_start=3), expected)


def test_spans_of_lines_render_like_whole_lines():
    """Units that are spans of lines (ranges starting and ending inside lines): the same
    pixels, and per-unit cost and rays that sum to the lines'."""
    state = studio()
    tracer = Tracer("t", cpus=1)
    tracer.sync_snapshot(encode_state(state))
    expected = reference(state, frame=1)
    units = WorkUnits(state.camera.width, state.camera.height, 8)
    cuts = [(0, 5), (5, 6), (6, 61), (61, units.count)]
    assert np.array_equal(rendered(tracer, 0, frame=1, ranges=cuts, spans=8), expected)
    whole = tracer.render(SceneEnvelope(version=0), FrameRequest(1, units=(0, state.camera.height)))
    spans = tracer.render(
        SceneEnvelope(version=0), FrameRequest(1, units=(0, units.count)), spans=8
    )
    assert np.array_equal(units.per_line(spans.cost), whole.cost)
    assert np.array_equal(units.per_line(spans.rays), whole.rays)


def test_a_pooled_call_renders_its_range_then_every_chunk_it_claims():
    """With a shared pool the call renders its own range, then claims chunks until none is
    left; each chunk's pixels are render_image's and the pool records who took them. A call
    with no range of its own only claims; a pool that is gone gives no chunks."""
    state = studio()
    tracer = Tracer("t", cpus=1)
    tracer.sync_snapshot(encode_state(state))
    expected = reference(state, frame=2).reshape(-1, state.camera.width, 3)
    pool = LinePool.create([(20, 24), (0, 3), (8, 9)])
    try:
        out = tracer.render(
            SceneEnvelope(version=0), FrameRequest(2, units=(3, 8)), pool=(pool.path, 5)
        )
        assert pool.claimed(5) == [(20, 24), (0, 3), (8, 9)]
    finally:
        pool.unlink()

    def lines(a: int, b: int) -> np.ndarray:
        return expected[a:b].reshape(-1, 3)

    assert (out.u0, out.u1) == (3, 8) and np.array_equal(out.rgb, lines(3, 8))
    assert [(c.u0, c.u1) for c in out.more] == [(20, 24), (0, 3), (8, 9)]
    for chunk in out.more:
        assert np.array_equal(chunk.rgb, lines(chunk.u0, chunk.u1))
        assert chunk.cost.shape == chunk.rays.shape == (chunk.u1 - chunk.u0,)
        assert chunk.seconds > 0.0 and chunk.apply_seconds == 0.0
    with LinePool.create([(9, 12)]) as second:
        only = tracer.render(
            SceneEnvelope(version=0), FrameRequest(2, units=(4, 4)), pool=(second.path, 0)
        )
        second.unlink()
    assert only.rgb.shape == (0, 3) and only.cost.shape == (0,)
    assert [(c.u0, c.u1) for c in only.more] == [(9, 12)]
    assert np.array_equal(only.more[0].rgb, lines(9, 12))
    late = tracer.render(
        SceneEnvelope(version=0), FrameRequest(2, units=(0, 1)), pool=(second.path, 0)
    )
    assert late.more is None and np.array_equal(late.rgb, lines(0, 1))  # no pool here


def test_commits_reach_exactly_the_version_asked_for():
    """Commit buffers apply in order and idempotently; the frame renders at its own version
    even after newer commits arrived (the replica keeps two)."""
    graph = SceneGraph(studio())
    tracer = Tracer("t", cpus=1)
    tracer.sync_snapshot(encode_state(graph.snapshot()))
    first = graph.commit([MOVE])
    state_1 = graph.state
    second = graph.commit([SKY])
    blobs = [encode_commit(first), encode_commit(second)]
    assert np.array_equal(rendered(tracer, 2, blobs), reference(graph.state))
    assert np.array_equal(rendered(tracer, 2, blobs), reference(graph.state))  # delivered twice
    assert np.array_equal(rendered(tracer, 1, []), reference(state_1))  # the older version


def test_out_of_sync_says_what_it_holds():
    """No scene, a gap in the commits, a version no longer held: OutOfSync with the version
    held, nothing rendered; a snapshot sent with the call repairs it."""
    graph = SceneGraph(studio())
    snapshot_0 = encode_state(graph.snapshot())
    tracer = Tracer("t", cpus=1)
    out = tracer.render(SceneEnvelope(version=0), FrameRequest(0, units=(0, 24)))
    assert isinstance(out, OutOfSync) and out.have is None and out.incarnation
    tracer.sync_snapshot(snapshot_0)
    commits = [encode_commit(graph.commit([MOVE])) for _ in range(1)]
    commits += [encode_commit(graph.commit([SKY])), encode_commit(graph.commit([MOVE]))]
    whole = FrameRequest(0, units=(0, 24))
    gap = tracer.render(SceneEnvelope(version=3, commits=[commits[0], commits[2]]), whole)
    assert isinstance(gap, OutOfSync) and gap.have == 1 and "cannot apply" in gap.reason
    assert isinstance(tracer.render(SceneEnvelope(version=3, commits=commits), whole), UnitsResult)
    dropped = tracer.render(
        SceneEnvelope(version=0), FrameRequest(0, units=(0, 24))
    )  # holds versions 2 and 3 only
    assert isinstance(dropped, OutOfSync) and dropped.have == 3
    repaired = rendered(tracer, 0, [], snapshot=snapshot_0)
    assert np.array_equal(repaired, reference(studio()))


def test_query_and_info():
    tracer = Tracer("probe", cpus=3)
    tracer.sync_snapshot(encode_state(studio()))
    hits = tracer.query([[-1.5, 3.5, 0.1]], [[0.0, -1.0, 0.0]])
    assert hits.material == ["white"] and hits.node[0] == 3
    info = tracer.info()
    assert (info.id, info.cpus, info.threads, info.version, info.pid) == (
        "probe",
        3.0,
        3,
        0,
        os.getpid(),
    )


def test_scenes_are_kept_apart_and_the_least_recently_used_is_dropped():
    """Replicas of several scenes under their keys: each renders its own pixels; past
    MAX_SCENES the least recently used goes, and a call for it says OutOfSync (have None)."""
    plain, moved = studio(), SceneGraph(studio())
    moved.commit([MOVE])
    tracer = Tracer("t", cpus=2)
    tracer.sync_snapshot(encode_state(plain), "plain")
    tracer.sync_snapshot(encode_state(moved.state), "moved")
    assert tracer.version("plain") == 0 and tracer.version("moved") == 1
    assert np.array_equal(rendered(tracer, 0, scene="plain"), reference(plain))
    assert np.array_equal(rendered(tracer, 1, scene="moved"), reference(moved.state))
    for k in range(MAX_SCENES - 1):  # "plain" was used before "moved": it goes first
        tracer.sync_snapshot(encode_state(plain), f"other-{k}")
    assert "plain" not in tracer.info().scenes and tracer.version("moved") == 1
    lost = tracer.render(SceneEnvelope("plain", 0), FrameRequest(0, units=(0, 24)))
    assert isinstance(lost, OutOfSync) and (lost.scene, lost.have) == ("plain", None)


def test_query_reaches_the_version_it_asks_for():
    """A query at a version the tracer does not hold yet applies the commits first; one it
    cannot reach answers OutOfSync."""
    graph = SceneGraph(studio())
    tracer = Tracer("q", cpus=1)
    tracer.sync_snapshot(encode_state(graph.state), "g")
    down = ([[0.5, 3.5, 0.3]], [[0.0, -1.0, 0.0]])  # straight down onto box-a once it moved
    before = tracer.query(*down, SceneEnvelope("g", 0))
    commit = graph.commit([MOVE])
    after = tracer.query(*down, SceneEnvelope("g", 1, [encode_commit(commit)]))
    assert before.node[0] != after.node[0] and after.t[0] < before.t[0]
    missing = tracer.query(*down, SceneEnvelope("g", 5))
    assert isinstance(missing, OutOfSync) and missing.have == 1


# --- as a Ray actor -------------------------------------------------------------------------


def test_actor_renders_from_a_snapshot_in_the_object_store(ray_session):
    """The snapshot is put once; the actor receives it by reference, renders in its own
    process and reports its pid and node."""
    graph = SceneGraph(studio())
    expected = reference(graph.state, frame=2)  # also compiles the kernel for the cache
    actor = remote_tracer(1).remote("a", 1)
    try:
        snapshot = ray.put(encode_state(graph.snapshot()))
        assert ray.get(actor.sync_snapshot.remote(snapshot)) == 0
        out = ray.get(actor.render.remote(SceneEnvelope(version=0), FrameRequest(2, units=(0, 24))))
        assert np.array_equal(out.rgb, expected.reshape(-1, 3))
        assert out.pid != os.getpid()
        assert out.node == ray.get_runtime_context().get_node_id()
        commit = encode_commit(graph.commit([MOVE]))
        out = ray.get(
            actor.render.remote(
                SceneEnvelope(version=1, commits=[commit]), FrameRequest(2, units=(0, 24))
            )
        )
        assert np.array_equal(out.rgb, reference(graph.state, frame=2).reshape(-1, 3))
        assert ray.get(actor.version.remote()) == 1
    finally:
        ray.kill(actor)


def test_actor_warm_starts_from_the_shared_kernel_cache(ray_session):
    """numba's cache directory is the driver's, and the actor loads the render kernel from it
    (a cache hit, no compile) once the driver has compiled it."""
    reference(studio())
    actor = remote_tracer(1).remote("w", 1)
    try:
        ray.get(actor.sync_snapshot.remote(encode_state(studio())))
        warm = ray.get(actor.warm_up.remote())
        assert warm["cache_dir"] == os.environ["NUMBA_CACHE_DIR"]
        assert warm["cache_misses"] == 0 and warm["cache_hits"] >= 1
        assert warm["seconds"] < 10.0
    finally:
        ray.kill(actor)


def when_back(call, seconds: float = 60.0):
    """``call()`` once the restarting actor takes calls (Ray may answer ActorUnavailableError
    while the new process starts)."""
    deadline = time.monotonic() + seconds
    while True:
        try:
            return call()
        except ray.exceptions.ActorUnavailableError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.2)


def test_a_restarted_actor_comes_back_empty_and_says_so(ray_session):
    """Killed mid-render, the call fails with RayActorError; Ray restarts the process (new pid
    and incarnation) with no scene, so a render answers OutOfSync until a snapshot comes."""
    state = studio()
    actor = remote_tracer(1).remote("k", 1, 5.0)  # test-only delay: 5 s before each render
    try:
        ray.get(actor.sync_snapshot.remote(encode_state(state)))
        before = ray.get(actor.info.remote())
        pending = actor.render.remote(SceneEnvelope(version=0), FrameRequest(0, units=(0, 24)))
        time.sleep(0.5)
        ray.kill(actor, no_restart=False)
        with pytest.raises(ray.exceptions.RayActorError):
            ray.get(pending, timeout=60)
        after = when_back(lambda: ray.get(actor.info.remote(), timeout=60))
        assert after.pid != before.pid and after.incarnation != before.incarnation
        assert after.version is None
        ray.get(actor.set_delay.remote(0.0))
        out = ray.get(actor.render.remote(SceneEnvelope(version=0), FrameRequest(0, units=(0, 24))))
        assert isinstance(out, OutOfSync) and out.have is None
        snapshot = ray.put(encode_state(state))
        out = ray.get(
            actor.render.remote(
                SceneEnvelope(version=0, snapshot=snapshot), FrameRequest(0, units=(0, 24))
            )
        )
        assert np.array_equal(out.rgb, reference(state).reshape(-1, 3))
    finally:
        ray.kill(actor)

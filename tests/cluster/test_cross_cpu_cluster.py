"""A frame whose units come from tracers on different CPUs is the frame one tracer renders.

Two tracer actors on the embedded Ray: one with the host's settings, one whose process runs
as an emulated other CPU (``tests/tracer/test_cross_cpu.py``: numba's code for that CPU in a
kernel cache of its own, OpenBLAS's kernels for it, numpy without the host's AVX-512), set
through Ray's ``runtime_env`` (``Coordinator.add_tracers(options=...)``). Each compiles its
own replica of the scene from the same snapshot; the assembled frame and its work per line
must equal, bit for bit, the frame the host tracer renders alone, and float64 ray queries
against the two replicas must agree (pixels alone round most last-bit differences away). The
emulated tracer compiles its kernels on first use (tens of seconds on two cores; the cache is
shared with the tracer test of the same CPU in one session)."""

import os
from pathlib import Path

import numpy as np
import pytest
import ray

from cluster.coordinator import Coordinator
from cluster.scene_graph import SceneGraph
from tests.cpu_variants import other_cpu
from tests.harsh_scene import harsh_scene
from tests.tracer.test_cross_cpu import (
    HIT_FIELDS,
    OUTDOOR,
    cached_cpu_names,
    differing,
    pytestmark,  # noqa: F401 - the same platform condition
    query_rays,
)
from tracer.request import FrameRequest
from tracer.scene.format import override
from tracer.scene.loader import load_scene
from worker.envelope import SceneEnvelope

WIDTH, HEIGHT, SPP = 48, 32, 2


def process_environment(pid: int) -> dict[str, str]:
    """The environment a process of this machine was started with."""
    raw = Path(f"/proc/{pid}/environ").read_bytes().split(b"\0")
    return dict(item.decode().split("=", 1) for item in raw if b"=" in item)


@pytest.mark.parametrize("scene", ["outdoor", "harsh"])
def test_tracer_on_another_cpu_renders_the_same_frame(
    ray_session, numba_target_cache, tmp_path, scene
):
    """One of two tracers runs as an emulated other CPU and renders half of the frame; the
    assembled frame equals the host tracer's frame alone, every bit, and both replicas answer
    ray queries with the same bits."""
    variant = other_cpu()
    if all(os.environ.get(k) == v for k, v in variant.env.items()):
        pytest.skip(f"this process already runs as the emulated {variant.name}")
    cache = numba_target_cache(variant.cache_key)
    env = {**variant.env, "TILERENDER_NUMBA_CACHE": str(cache)}
    path = OUTDOOR if scene == "outdoor" else harsh_scene(tmp_path / "harsh")
    state = load_scene(path)
    camera = override(state.camera, width=WIDTH, height=HEIGHT)
    settings = override(state.render, spp=SPP)
    # A static even split, no pool and no straggler copies: each tracer renders its own half.
    with Coordinator(
        SceneGraph(state),
        tracers=1,
        cpus_per_tracer=1,
        balancer="none",
        line_pool=False,
        straggler_floor=600.0,
    ) as coordinator:
        alone = coordinator.render_frame(FrameRequest(0, camera, settings))
        (host,) = [t["id"] for t in coordinator.tracers()]
        (other,) = coordinator.add_tracers(1, cpus=1, options={"runtime_env": {"env_vars": env}})
        both = coordinator.render_frame(FrameRequest(0, camera, settings))
        tracers = {t["id"]: t for t in coordinator.tracers()}
        started_with = process_environment(tracers[other]["pid"])
        host_env = process_environment(tracers[host]["pid"])
        # float64 ray queries against each tracer's own replica: a last-bit difference in
        # its compiled scene or intersection code shows here even where pixels round it away.
        queries = {
            (t, label): ray.get(
                coordinator.tracer_handle(t).query.remote(
                    o, d, SceneEnvelope(coordinator.graph.key)
                )
            )
            for t in (host, other)
            for label, o, d in query_rays(state.camera)
        }

    # The emulated tracer's process really runs with the variant's settings and kernels.
    assert {k: started_with.get(k) for k in env} == env
    assert any(host_env.get(k) != v for k, v in variant.env.items())
    assert Path(tracers[other]["warm_up"]["cache_dir"]).parent == cache
    assert Path(tracers[host]["warm_up"]["cache_dir"]).parent != cache
    assert cached_cpu_names(cache) == {variant.numba}

    # Both tracers rendered a real share of the frame, as split, without copies or losses.
    assert {r.tracer for r in alone.ranges} == {host}
    units = {t: sum(r.u1 - r.u0 for r in both.ranges if r.tracer == t) for t in (host, other)}
    assert units[host] > 0 and units[other] > 0
    assert sum(units.values()) == both.units.count
    assert all(r.kind == "split" for r in both.ranges)
    assert (both.duplicates, both.reassigned, both.failures) == (0, 0, 0)

    assert alone.rgb.shape == (HEIGHT, WIDTH, 3) and alone.rgb.std() > 0.02
    assert differing(both.rgb, alone.rgb) == 0
    assert np.array_equal(both.rgb, alone.rgb) and both.rgb.tobytes() == alone.rgb.tobytes()
    assert np.array_equal(both.cost, alone.cost)
    for label, _, _ in query_rays(state.camera):
        mine, theirs = queries[host, label], queries[other, label]
        assert (mine.node >= 0).mean() > 0.5
        for key in HIT_FIELDS:
            assert getattr(mine, key).tobytes() == getattr(theirs, key).tobytes(), (label, key)

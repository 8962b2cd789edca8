"""The actor pool of tracers on several machines: chunks handed out in order, each exactly once
however many tracers claim at the same time, every claim recording its owner; a tracer renders
its head and then the chunks it claims, bit-identical to render_image."""

import threading

import numpy as np
import pytest

from tests.worker.test_replica import studio
from tracer.compiled.scene import compile_scene
from tracer.render import render_image
from tracer.request import FrameRequest
from tracer.scene.codec import encode_state
from worker.envelope import SceneEnvelope
from worker.remote_pool import WAIT, PoolTables, RemotePool, remote_tables
from worker.tracer_actor import Tracer


def test_tables_hand_chunks_out_in_order_and_record_owners():
    tables = PoolTables()
    assert tables.open(0, [(5, 9), (0, 5), (9, 10)]) == 3
    tables.open(1, [(0, 1)])
    assert tables.claim(0, 2) == (5, 9)
    assert tables.claim(0, 7) == (0, 5)
    assert tables.rows(0) == [(5, 9, 2), (0, 5, 7), (9, 10, -1)]
    assert tables.claim(1, 1) == (0, 1) and tables.claim(1, 1) is None  # tables apart
    assert tables.claim(0, 2) == (9, 10) and tables.claim(0, 2) is None
    tables.close(0)
    assert tables.claim(0, 2) is None and tables.rows(0) == []  # closed
    assert tables.claim(2, 0) == WAIT  # above the newest table: its open is on its way
    with pytest.raises(ValueError, match="empty"):
        tables.open(3, [(3, 3)])


def test_racing_claims_get_every_chunk_exactly_once(ray_session):
    """Four claimers (each sending its next claim ahead) drain 400 chunks: every chunk is
    taken once, by the owner the table records."""
    import ray

    tables = remote_tables(ray.get_runtime_context().get_node_id())
    chunks = [(k, k + 1) for k in range(400)]
    pool = RemotePool.create(tables, chunks, 0)
    taken: dict[int, list[tuple[int, int]]] = {}

    def drain(owner: int) -> None:
        taken[owner] = list(RemotePool(tables, pool.key).claims(owner))

    threads = [threading.Thread(target=drain, args=(owner,)) for owner in range(4)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(timeout=60)
    claimed = sorted(chunk for mine in taken.values() for chunk in mine)
    assert claimed == chunks
    for owner, mine in taken.items():
        assert sorted(pool.claimed(owner)) == sorted(mine)
    assert pool.unclaimed() == []
    pool.unlink()
    ray.kill(tables)


def test_a_tracer_renders_its_head_then_the_chunks_it_claims(ray_session):
    import ray

    state = studio()
    tracer = Tracer("t", cpus=1)
    tracer.sync_snapshot(encode_state(state))
    expected = render_image(compile_scene(state), frame=2)[0].reshape(-1, 3)
    width = state.camera.width
    tables = remote_tables(ray.get_runtime_context().get_node_id())
    pool = RemotePool.create(tables, [(20, 24), (0, 3), (8, 9)], 0)
    out = tracer.render(
        SceneEnvelope(version=0), FrameRequest(2, units=(3, 8)), pool=(pool.ticket, 5)
    )
    assert pool.claimed(5) == [(20, 24), (0, 3), (8, 9)]
    assert np.array_equal(out.rgb, expected[3 * width : 8 * width])
    assert [(c.u0, c.u1) for c in out.more] == [(20, 24), (0, 3), (8, 9)]
    for chunk in out.more:
        assert np.array_equal(chunk.rgb, expected[chunk.u0 * width : chunk.u1 * width])
    pool.unlink()
    late = tracer.render(
        SceneEnvelope(version=0), FrameRequest(2, units=(0, 1)), pool=(pool.ticket, 5)
    )
    assert late.more == []  # closed: nothing left to claim
    ray.kill(tables)


def test_a_lost_pool_actor_ends_the_claims_not_the_render(ray_session):
    """The pool actor dies: claims raise PoolLost, and a tracer's pooled call still returns
    its head (the coordinator hands out the chunks nobody delivered)."""
    import ray

    from worker.remote_pool import PoolLost

    state = studio()
    tracer = Tracer("t", cpus=1)
    tracer.sync_snapshot(encode_state(state))
    tables = remote_tables(ray.get_runtime_context().get_node_id())
    pool = RemotePool.create(tables, [(9, 12)], 0)
    ray.kill(tables)
    with pytest.raises(PoolLost):
        pool.claimed()
    out = tracer.render(
        SceneEnvelope(version=0), FrameRequest(2, units=(3, 8)), pool=(pool.ticket, 1)
    )
    assert (out.u0, out.u1) == (3, 8) and out.more == []

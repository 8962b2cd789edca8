"""The authoritative scene graph (``cluster.scene_graph``): atomic versioned commits, the
bounded log, catching replicas up, and animation frames."""

import dataclasses
import threading

import numpy as np
import pytest

from cluster.scene_graph import SceneGraph
from tests.scene_states import small_state, spinning_animation, translation
from tracer.errors import SceneError
from tracer.scene import ops as so


def move(node, x: float) -> dict:
    return {"op": "set_transform", "node": node, "transform": {"translate": [x, 0, 0]}}


def test_commit_bumps_the_version_and_logs():
    graph = SceneGraph(small_state(version=4))
    commit = graph.commit([move("cube", 1.0), so.SetKind(node=1, kind="rigid")])
    assert commit.version == 5 == graph.version == graph.state.version
    assert [op.op for op in commit.ops] == ["set_transform", "set_kind"]
    np.testing.assert_array_equal(graph.state.nodes[2].transform, translation(1, 0, 0))
    assert graph.commits_since(4) == [commit]
    assert graph.snapshot() is graph.state


def test_a_failing_commit_changes_nothing():
    """The last op fails: state, version and log are exactly as before."""
    graph = SceneGraph(small_state())
    first = graph.commit([move(2, 1.0)])
    before = graph.state
    with pytest.raises(SceneError, match=r"op 2 \(remove_mesh\): mesh 'quad' is used by node 1"):
        graph.commit(
            [
                move(2, 9.0),
                {"op": "remove_node", "node": "lamp"},
                {"op": "remove_mesh", "mesh": "quad"},
            ]
        )
    assert graph.state is before and graph.version == 1
    assert graph.commits_since(0) == [first]
    np.testing.assert_array_equal(graph.state.nodes[2].transform, translation(1, 0, 0))
    with pytest.raises(SceneError, match=r"op 1 \(set_sky\): radiance"):
        graph.commit([move(2, 3.0), {"op": "set_sky", "radiance": [1, 1, -1]}])
    with pytest.raises(SceneError, match="at least one operation"):
        graph.commit([])
    assert graph.state is before and graph.commits_since(0) == [first]


def test_replicas_reach_the_same_state_by_commits():
    """Commits from the log, applied in order to an old state, reproduce the graph's state;
    re-delivered commits are ignored."""
    start = small_state()
    graph = SceneGraph(start)
    for x in range(5):
        graph.commit([move("cube", float(x)), {"op": "set_sky", "radiance": [x, x, x]}])
    replica = start
    for commit in graph.commits_since(0) + graph.commits_since(3):
        replica = so.apply_commit(replica, commit)
    assert replica.version == 5 and replica.sky == graph.state.sky
    np.testing.assert_array_equal(replica.nodes[2].transform, graph.state.nodes[2].transform)
    assert replica.nodes[1] is start.nodes[1] is graph.state.nodes[1]


def test_commits_since_and_sync_with_a_trimmed_log():
    graph = SceneGraph(small_state(version=10), log_limit=3)
    commits = [graph.commit([move(2, float(x))]) for x in range(5)]
    assert [c.version for c in commits] == [11, 12, 13, 14, 15]
    assert graph.commits_since(15) == []
    assert graph.commits_since(14) == commits[4:]
    assert graph.commits_since(12) == commits[2:]
    assert graph.commits_since(11) is None, "commit 12 has left the log"
    assert graph.commits_since(9) is None
    assert graph.commits_since(16) is None, "a replica from the future"
    assert graph.sync(13) == ("commits", commits[3:])
    assert graph.sync(15) == ("commits", [])
    kind, state = graph.sync(11)
    assert kind == "snapshot" and state is graph.state
    assert graph.sync(99)[0] == "snapshot"


def test_a_new_graph_has_no_history_and_no_log_keeps_none():
    graph = SceneGraph(small_state(version=7))
    assert graph.sync(7) == ("commits", [])
    assert graph.sync(6)[0] == "snapshot"
    unlogged = SceneGraph(small_state(), log_limit=0)
    unlogged.commit([move(2, 1.0)])
    assert unlogged.commits_since(1) == [] and unlogged.commits_since(0) is None
    with pytest.raises(ValueError, match="log_limit"):
        SceneGraph(small_state(), log_limit=-1)


def test_an_inconsistent_initial_state_is_refused():
    state = small_state()
    orphan = dataclasses.replace(state.nodes[1], parent=42)
    with pytest.raises(SceneError, match=r"node 1 .*: parent 42 does not exist"):
        SceneGraph(dataclasses.replace(state, nodes={**state.nodes, 1: orphan}))


def test_frame_commits_follow_the_animation():
    graph = SceneGraph(small_state(animation=spinning_animation()))
    assert graph.frame_commit(0) is None, "frame 0 is the state's own pose"
    commit = graph.frame_commit(2)
    assert commit.version == 1 and [op.op for op in commit.ops] == ["set_transform", "set_camera"]
    assert graph.state.camera.vfov_deg == 50.0
    assert graph.frame_commit(2) is None and graph.version == 1
    assert graph.frame_commit(4).version == 2
    assert graph.frame_commit(0).version == 3
    with pytest.raises(SceneError, match="frame 5 is not one of"):
        graph.frame_commit(5)
    assert SceneGraph(small_state()).frame_commit(0) is None


def test_concurrent_commits_are_serialised():
    """Eight threads commit 25 times each: every version appears once and the log is gapless."""
    graph = SceneGraph(small_state(), log_limit=1000)

    def work(i: int) -> None:
        for k in range(25):
            graph.commit([move(2, float(i * 100 + k))])

    threads = [threading.Thread(target=work, args=(i,)) for i in range(8)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    log = graph.commits_since(0)
    assert graph.version == 200 and [c.version for c in log] == list(range(1, 201))
    last = log[-1].ops[0].transform.translate[0]
    assert graph.state.nodes[2].transform[0, 3] == last

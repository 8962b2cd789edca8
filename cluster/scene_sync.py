"""What each tracer holds of each scene, and what it is sent to reach a version.

A tracer's calls carry a :class:`worker.envelope.SceneEnvelope`: the commit buffer from the
version the coordinator believes the tracer holds (once its earlier calls ran) to the call's
version, or the snapshot at that version when it holds nothing usable (new, restarted, or
further behind than the graph's log). Snapshots are ``ray.put`` once per scene and version and
shared by every tracer through the object store, as are commit buffers over
``INLINE_COMMITS`` bytes. A tracer that answers ``OutOfSync`` gets :meth:`SceneSync.resync`:
the commits from the version it says it holds, or a snapshot.
"""

import time
from collections import OrderedDict
from collections.abc import Callable
from typing import Any, Protocol

import ray
from ray.exceptions import GetTimeoutError, RayError

from cluster.errors import ClusterError
from cluster.scene_graph import SceneGraph
from tracer.scene.codec import encode_commit, encode_state
from tracer.scene.model import SceneState
from worker.envelope import SceneEnvelope
from worker.tracer_actor import MAX_SCENES, OutOfSync

SNAPSHOTS_KEPT = 4
COMMITS_KEPT = 4096
INLINE_COMMITS = 64 * 1024
"""Commit buffers larger than this many bytes go through the object store (put once, shared
by every tracer that needs the same buffer) instead of inside each call."""
BUFFERS_KEPT = 8


class Holder(Protocol):
    """A tracer as scene sync sees it: its id and, per scene key, the version it will hold
    once its submitted calls ran (least recently used first, as the tracer keeps them)."""

    id: str
    synced: OrderedDict[str, int]


def held(tracer: Holder, scene: str) -> int | None:
    """The version of ``scene`` the coordinator believes ``tracer`` holds (None: none)."""
    return tracer.synced.get(scene)


def hold(tracer: Holder, scene: str, version: int | None) -> None:
    """Record that ``tracer`` holds ``version`` of ``scene`` (None: nothing), mirroring the
    tracer's most-recently-used order and its limit of ``MAX_SCENES``."""
    tracer.synced.pop(scene, None)
    if version is not None:
        tracer.synced[scene] = version
        while len(tracer.synced) > MAX_SCENES:
            tracer.synced.popitem(last=False)


class SceneSync:
    """Encoded snapshots and commit buffers for tracers, cached by scene and version."""

    def __init__(self) -> None:
        self._snapshots: OrderedDict[tuple[str, int], Any] = OrderedDict()
        self._commit_blobs: OrderedDict[tuple[str, int], bytes] = OrderedDict()
        self._buffers: OrderedDict[tuple[str, int, int], Any] = OrderedDict()

    def snapshot(self, graph: SceneGraph, state: SceneState) -> SceneEnvelope:
        """Reach ``state`` of ``graph`` from its snapshot (put once per scene and version)."""
        key = (graph.key, state.version)
        ref = self._snapshots.get(key)
        if ref is None:
            ref = self._snapshots[key] = ray.put(encode_state(state))
            while len(self._snapshots) > SNAPSHOTS_KEPT:
                self._snapshots.popitem(last=False)
        return SceneEnvelope(graph.key, state.version, [], ref)

    def envelope(self, tracer: Holder, graph: SceneGraph, state: SceneState) -> SceneEnvelope:
        """What ``tracer`` is sent to reach ``state`` of ``graph`` from what it holds."""
        return self._from(held(tracer, graph.key), graph, state)

    def sent(self, tracer: Holder, envelope: SceneEnvelope, have: int | None) -> None:
        """``envelope`` went to ``tracer``, which held ``have`` before: once it runs, the
        tracer holds the envelope's version (a snapshot; commits from a version it held)."""
        if envelope.snapshot is not None:
            hold(tracer, envelope.scene, envelope.version)
        elif have is not None:
            hold(tracer, envelope.scene, max(have, envelope.version))

    def resync(
        self, tracer: Holder, out: OutOfSync, graph: SceneGraph, state: SceneState, last: bool
    ) -> SceneEnvelope:
        """The one resync rule: ``tracer`` answered ``out``; what it is sent again. The
        commits from the version it holds, or the snapshot when it holds none, holds the
        version already (so dropped it) or this is the ``last`` try."""
        hold(tracer, out.scene, out.have)
        if out.have is None or out.have >= state.version or last:
            return self.snapshot(graph, state)
        return self._from(out.have, graph, state)

    def _from(self, have: int | None, graph: SceneGraph, state: SceneState) -> SceneEnvelope:
        """The envelope from ``have`` of ``graph`` to ``state``: no data if it is there (if it
        is not, it says OutOfSync), the commits (a reference to them when large), or the
        snapshot when the graph's log does not reach back to ``have``."""
        version = state.version
        if have is not None and have >= version:
            return SceneEnvelope(graph.key, version)
        commits = None if have is None else self._commits(graph, have, version)
        if commits is None:
            return self.snapshot(graph, state)
        if sum(len(c) for c in commits) <= INLINE_COMMITS:
            return SceneEnvelope(graph.key, version, commits)
        key = (graph.key, have, version)
        ref = self._buffers.get(key)
        if ref is None:
            ref = self._buffers[key] = ray.put(commits)
            while len(self._buffers) > BUFFERS_KEPT:
                self._buffers.popitem(last=False)
        return SceneEnvelope(graph.key, version, ref)

    def _commits(self, graph: SceneGraph, since: int, version: int) -> list[bytes] | None:
        """Encoded commits taking a replica of ``graph`` from ``since`` to ``version``; None if
        the graph's log does not reach back that far."""
        commits = graph.commits_since(since)
        if commits is None:
            return None
        blobs = []
        for commit in commits:
            if commit.version > version:
                break
            key = (graph.key, commit.version)
            blob = self._commit_blobs.get(key)
            if blob is None:
                blob = self._commit_blobs[key] = encode_commit(commit)
                while len(self._commit_blobs) > COMMITS_KEPT:
                    self._commit_blobs.popitem(last=False)
            blobs.append(blob)
        return blobs

    def run(
        self,
        graph: SceneGraph,
        state: SceneState,
        calls: list[tuple[Holder, Callable[[SceneEnvelope], Any]]],
        timeout: float,
    ) -> list[Any]:
        """Run ``(tracer, call)`` pairs, all in flight at once: ``call(envelope)`` is an actor
        call that first reaches ``state`` of ``graph``; a tracer that answers
        :class:`OutOfSync` is asked once more (:meth:`resync`, its last try). Within
        ``timeout`` seconds for them all, retries included; a call not done by then is
        cancelled (if still queued: a running one finishes, and its result is dropped). Per
        call, its result, or the error (a ``ClusterError`` or Ray's) that ended it."""
        deadline = time.perf_counter() + timeout
        pending = []
        for tracer, call in calls:
            have = held(tracer, graph.key)
            pending.append((tracer, call, have, call(self._from(have, graph, state))))
        results = []
        for tracer, call, have, ref in pending:
            try:
                out = _get_by(ref, deadline)
                if isinstance(out, OutOfSync):
                    out = _get_by(call(self.resync(tracer, out, graph, state, last=True)), deadline)
                if isinstance(out, OutOfSync):
                    hold(tracer, graph.key, out.have)
                    raise ClusterError(
                        f"tracer {tracer.id} cannot reach version {state.version}: {out.reason}"
                    )
                hold(tracer, graph.key, max(have or 0, state.version))
            except (ClusterError, RayError) as error:
                out = error
            results.append(out)
        return results

    def clear(self) -> None:
        """Forget every snapshot and buffer (the coordinator closes)."""
        self._snapshots.clear()
        self._buffers.clear()


def _get_by(ref, deadline: float) -> Any:
    """``ray.get`` of ``ref`` by ``deadline`` (a ``perf_counter`` time); a call not done by
    then is cancelled (Ray drops it if still queued) and raises ``GetTimeoutError``."""
    try:
        return ray.get(ref, timeout=max(0.0, deadline - time.perf_counter()))
    except GetTimeoutError:
        ray.cancel(ref)
        raise

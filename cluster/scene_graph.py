"""The authoritative, versioned scene (Brigade's scene graph, Bikker 7.3.1-7.3.4).

Every change is a :class:`~tracer.scene.ops.Commit` that takes version ``v`` to ``v + 1``. The
graph keeps the last ``log_limit`` commits, so a replica that is a little behind catches up by
applying them in order; one that is further behind (or new) gets a snapshot instead.

Each graph has a ``key`` (unique unless given): tracers keep replicas of several graphs under
their keys, so one coordinator can render many scenes in turns.
"""

import threading
import uuid
from collections import deque
from collections.abc import Iterable, Mapping
from itertools import islice

from tracer.errors import SceneError
from tracer.scene.animation import animation_ops
from tracer.scene.checks import check_state
from tracer.scene.model import SceneState
from tracer.scene.ops import Commit, Op, apply_commit, parse_ops


class SceneGraph:
    """The current scene state and a bounded log of the commits that led to it. Thread-safe:
    commits are applied one at a time, and readers see a state and log that belong together."""

    def __init__(self, state: SceneState, log_limit: int = 1024, key: str | None = None) -> None:
        if log_limit < 0:
            raise ValueError(f"log_limit must be at least 0, not {log_limit}")
        check_state(state)
        self.key = key or uuid.uuid4().hex
        """Names this graph's replicas on the tracers."""
        self._state = state
        self._log: deque[Commit] = deque(maxlen=log_limit)
        self._lock = threading.Lock()

    @property
    def state(self) -> SceneState:
        """The current state (immutable; later commits replace it, never change it)."""
        return self._state

    @property
    def version(self) -> int:
        return self._state.version

    def snapshot(self) -> SceneState:
        """The current state, for a replica that cannot catch up with commits."""
        return self._state

    def commit(self, ops: Iterable[Mapping | Op]) -> Commit:
        """Apply ``ops`` (models or JSON-like dicts) as one commit and return it.

        All or nothing: on any error SceneError is raised and the state, version and log stay
        as they were. An empty list is refused (a commit always changes the version).
        """
        parsed = parse_ops(ops)
        with self._lock:
            return self._commit(parsed)

    def frame_commit(self, frame: int) -> Commit | None:
        """Commit the animation's pose at ``frame``; None when that changes nothing."""
        with self._lock:
            ops = animation_ops(self._state, frame)
            return self._commit(tuple(ops)) if ops else None

    def commits_since(self, version: int) -> list[Commit] | None:
        """The commits that take a replica at ``version`` to the current version, in order;
        None if the log no longer reaches back that far or ``version`` is in the future."""
        with self._lock:
            return self._commits_since(version)

    def sync(self, version: int) -> tuple[str, object]:
        """What a replica at ``version`` needs: ``("commits", [...])`` (possibly empty) or
        ``("snapshot", state)``."""
        with self._lock:
            commits = self._commits_since(version)
            return ("snapshot", self._state) if commits is None else ("commits", commits)

    def _commit(self, ops: tuple[Op, ...]) -> Commit:
        if not ops:
            raise SceneError("a commit needs at least one operation")
        commit = Commit(self._state.version + 1, ops)
        self._state = apply_commit(self._state, commit)
        self._log.append(commit)
        return commit

    def _commits_since(self, version: int) -> list[Commit] | None:
        current = self._state.version
        if version > current:
            return None
        if version == current:
            return []
        if not self._log or self._log[0].version > version + 1:
            return None
        return list(islice(self._log, version + 1 - self._log[0].version, None))

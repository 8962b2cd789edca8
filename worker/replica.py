"""A tracer's replica of the scene (Brigade, Bikker 7.3.1-7.3.4).

The cluster owns the authoritative scene graph; a replica starts from a snapshot and applies
commit buffers in version order. Each version compiles incrementally from the previous one
(``tracer.compiled.scene``): unchanged meshes, pools and BVHs are shared, moved vertices refit, and
only the top level is rebuilt for rigid motion. Compiled versions are immutable, and the
replica keeps the ones frames may still be using, so a frame in flight keeps the version it
was scheduled at while newer commits are applied (double buffering).
"""

from collections import OrderedDict

import numpy as np

from tracer import config
from tracer.compiled.scene import CompiledScene, compile_scene
from tracer.errors import SceneError
from tracer.geometry.query import SceneHits, scene_hits
from tracer.scene.codec import decode_commit, decode_state
from tracer.scene.model import SceneState
from tracer.scene.ops import Commit, CommitGap, apply_commit

KEEP_VERSIONS = 2
"""Compiled versions kept: the one rendering and the one being prepared."""


class SceneReplica:
    """A scene at a version, kept compiled. Not thread-safe: one owner applies commits."""

    def __init__(
        self,
        snapshot: SceneState | bytes,
        keep: int = KEEP_VERSIONS,
        rebuild_threshold: float = config.BVH_REBUILD_THRESHOLD,
    ):
        """``rebuild_threshold``: what deformed meshes get
        (``tracer.compiled.scene.compile_scene``)."""
        self._keep = max(1, keep)
        self._rebuild_threshold = rebuild_threshold
        self._compiled: OrderedDict[int, CompiledScene] = OrderedDict()
        self.reset(snapshot)

    @property
    def version(self) -> int:
        return next(reversed(self._compiled))

    @property
    def state(self) -> SceneState:
        return self.current.state

    @property
    def current(self) -> CompiledScene:
        """The newest compiled version."""
        return self._compiled[self.version]

    @property
    def versions(self) -> list[int]:
        """Versions held, oldest first."""
        return list(self._compiled)

    def reset(self, snapshot: SceneState | bytes) -> None:
        """Start over from a snapshot (a new or lagging replica): everything is compiled."""
        state = decode_state(snapshot) if isinstance(snapshot, bytes) else snapshot
        compiled = compile_scene(state)
        self._compiled.clear()
        self._compiled[state.version] = compiled

    def apply(self, commits: list[Commit | bytes]) -> int:
        """Apply commits in order; ones already applied are skipped (idempotent delivery).

        Raises ``CommitGap`` if a commit is missing (the replica then needs a snapshot), and
        ``SceneError`` for a commit that cannot apply: in both cases the replica is left at the
        last good version. Returns the new version.
        """
        for item in commits:
            commit = decode_commit(item) if isinstance(item, bytes) else item
            if commit.version <= self.version:
                continue
            if commit.version != self.version + 1:
                raise CommitGap(
                    f"replica at version {self.version} cannot apply commit {commit.version}"
                )
            state = apply_commit(self.state, commit)
            compiled = compile_scene(state, self.current, self._rebuild_threshold)
            self._compiled[commit.version] = compiled
            while len(self._compiled) > self._keep:
                self._compiled.popitem(last=False)
        return self.version

    def at(self, version: int) -> CompiledScene:
        """The compiled scene at exactly ``version`` (it must still be held)."""
        try:
            return self._compiled[version]
        except KeyError:
            raise SceneError(
                f"version {version} is not held by this replica (it holds {self.versions})"
            ) from None

    def query(
        self,
        origins: np.ndarray,
        directions: np.ndarray,
        version: int | None = None,
        t_max: float | None = None,
    ) -> SceneHits:
        """Single or batched ray queries (Bikker 7.3.6) against a held version (default the
        newest): node, triangle, distance, point, normal and material per ray."""
        scene = self.current if version is None else self.at(version)
        return scene_hits(scene, origins, directions, t_max, threads=1)

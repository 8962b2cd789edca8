"""What a tracer must hold before it does anything with a scene: one version of it, and how to
get there (commits since the version it is believed to hold, or a snapshot)."""

import sys
from dataclasses import dataclass, replace
from typing import Any

DEFAULT_SCENE = "default"
"""The scene key of calls that name none (a tracer serving one scene)."""


@dataclass(frozen=True)
class SceneEnvelope:
    """Reach ``version`` of scene ``scene`` (None: the newest held, a query only), first
    applying ``commits`` (encoded, in version order; ones already applied are skipped), or
    starting from ``snapshot`` when given and needed.

    ``commits`` and ``snapshot`` may be Ray object references (a large buffer, a snapshot put
    once for every tracer): :meth:`fetched` resolves them in the tracer.
    """

    scene: str = DEFAULT_SCENE
    version: int | None = None
    commits: Any = ()
    """Encoded commits (``tracer.scene.codec.encode_commit``), or a reference to a list of
    them."""
    snapshot: Any = None
    """An encoded state (``tracer.scene.codec.encode_state``), a reference to one, or None."""

    def fetched(self) -> "SceneEnvelope":
        """This envelope with object references replaced by their values."""
        commits, snapshot = self.commits, self.snapshot
        if not _is_ref(commits) and not _is_ref(snapshot):
            return self
        get = sys.modules["ray"].get
        return replace(
            self,
            commits=get(commits) if _is_ref(commits) else commits,
            snapshot=get(snapshot) if _is_ref(snapshot) else snapshot,
        )


def _is_ref(value: Any) -> bool:
    """Whether ``value`` is a Ray object reference (there is none unless Ray is imported)."""
    ray = sys.modules.get("ray")
    return ray is not None and isinstance(value, ray.ObjectRef)

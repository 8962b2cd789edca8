"""One frame to render, as every layer from the front doors to the kernel speaks of it."""

from dataclasses import dataclass, replace

from tracer.errors import SceneError
from tracer.scene import format as fmt
from tracer.scene.model import SceneState


@dataclass(frozen=True)
class FrameRequest:
    """Frame ``frame`` of a scene at ``version``, seen by ``camera`` with ``settings``: the
    samples ``[sample_start, sample_start + settings.spp)`` of each pixel, of the work units
    ``units`` (a tracer's share; None for the whole frame).

    ``camera``, ``settings`` and ``version`` left None mean the scene's own at the version a
    frame is scheduled at; :meth:`resolved` fills them in.
    """

    frame: int = 0
    camera: fmt.Camera | None = None
    settings: fmt.RenderSettings | None = None
    sample_start: int = 0
    version: int | None = None
    units: tuple[int, int] | None = None

    def __post_init__(self) -> None:
        if self.frame < 0 or self.sample_start < 0:
            raise SceneError(
                f"frame and sample_start must be non-negative, got {self.frame} and "
                f"{self.sample_start}"
            )

    def resolved(self, state: SceneState) -> "FrameRequest":
        """This request with the camera, settings and version of ``state`` where it left them
        open."""
        return replace(
            self,
            camera=self.camera or state.camera,
            settings=self.settings or state.render,
            version=state.version if self.version is None else self.version,
        )

    def for_units(self, u0: int, u1: int) -> "FrameRequest":
        """The share ``[u0, u1)`` of this (resolved) frame."""
        return replace(self, units=(u0, u1))

    @property
    def spp(self) -> int:
        """Samples per pixel of a resolved request."""
        return self.settings.spp

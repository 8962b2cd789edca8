"""One frame to render, as every layer from the front doors to the kernel speaks of it."""

from dataclasses import dataclass, field, replace

import numpy as np

from tracer.errors import SceneError
from tracer.scene import format as fmt
from tracer.scene.model import SceneState


@dataclass(frozen=True)
class FrameRequest:
    """Frame ``frame`` of a scene at ``version``, seen by ``camera`` with ``settings``: the
    samples ``[sample_start, sample_start + settings.spp)`` of each pixel, of the pixel run
    ``region`` (row-major ``[r0, r1)``; None for the whole frame), of the work units ``units``
    of that region (a tracer's share; None for all of it).

    A region is whole lines, or a run inside one line: its :meth:`view` is then the
    rectangle its units are cut from, and its pixels get the bits they get in the whole frame.

    ``counts`` (int32, one per pixel of the frame, row-major, each in [1, ``settings.spp``])
    gives pixel ``i`` only the samples ``[sample_start, sample_start + counts[i])`` (adaptive
    sampling, ``cluster.adaptive``); None gives every pixel all of them.

    ``camera``, ``settings`` and ``version`` left None mean the scene's own at the version a
    frame is scheduled at; :meth:`resolved` fills them in.
    """

    frame: int = 0
    camera: fmt.Camera | None = None
    settings: fmt.RenderSettings | None = None
    sample_start: int = 0
    version: int | None = None
    units: tuple[int, int] | None = None
    region: tuple[int, int] | None = None
    counts: np.ndarray | None = field(default=None, compare=False, repr=False)

    def __post_init__(self) -> None:
        if self.frame < 0 or self.sample_start < 0:
            raise SceneError(
                f"frame and sample_start must be non-negative, got {self.frame} and "
                f"{self.sample_start}"
            )
        if self.region is not None and self.camera is not None:
            self.view()  # checks the region

    def view(self) -> tuple[int, int]:
        """(width, height) of what a resolved request renders: the frame, or its region as
        lines of the frame's width, or as one line of the run's length."""
        width, height = self.camera.width, self.camera.height
        if self.region is None:
            return width, height
        r0, r1 = self.region
        if not 0 <= r0 < r1 <= width * height:
            raise SceneError(
                f"region [{r0}, {r1}) is not a pixel run of the {width}x{height} frame"
            )
        if r0 % width == 0 and r1 % width == 0:
            return width, (r1 - r0) // width
        if r0 // width != (r1 - 1) // width:
            raise SceneError(f"region [{r0}, {r1}) is neither whole lines nor inside one line")
        return r1 - r0, 1

    @property
    def first_pixel(self) -> int:
        """The frame's pixel index of the region's first pixel (0 without a region)."""
        return 0 if self.region is None else self.region[0]

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

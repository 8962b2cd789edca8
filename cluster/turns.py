"""A frame rendered in bounded turns, so one caller's big frame never holds the coordinator
for long: the frame is cut into pixel runs (:attr:`FrameRequest.region`: whole lines, or a run
inside one line when a line alone takes longer than a turn), each sized from the rate measured
so far to take about ``TurnSizer.seconds``, and each rendered as a coordinator frame of its
own. Between two runs the caller may do other work on the coordinator (the service gives
sessions and calls their turns) or stop.

Every pixel gets the bits it gets in a frame rendered whole (a region's pixels are the
frame's), so the image does not depend on how the turns fell.
"""

import time
from collections.abc import Callable, Generator
from dataclasses import dataclass, replace

import numpy as np

from cluster.frame import Frame
from tracer.accuracy.error_estimate import PARTS
from tracer.accuracy.spot_check import SpotCheck
from tracer.integrators.aov import CHANNELS
from tracer.request import FrameRequest

FIRST_TURN_SAMPLES = 1 << 16
"""Samples of the first turn, before any rate is known (a few milliseconds of work)."""
GROWTH = 4.0
"""Most a turn's samples may grow over the turn before it."""


@dataclass
class TurnSizer:
    """How many samples the next turn takes: about ``seconds`` at the last turn's rate."""

    seconds: float
    rate: float | None = None
    """Seconds per sample of the last turn (None before the first)."""
    last_samples: int = 0
    seconds_total: float = 0.0
    """Seconds of every turn observed."""

    def samples(self) -> int:
        """Samples the next turn should take (at least one)."""
        if self.rate is None:
            return FIRST_TURN_SAMPLES
        fit = self.seconds / max(self.rate, 1e-12)
        return max(1, int(min(fit, GROWTH * max(self.last_samples, 1))))

    def observe(self, samples: int, seconds: float) -> None:
        """A turn of ``samples`` samples took ``seconds``."""
        self.seconds_total += seconds
        if samples > 0 and seconds > 0.0:
            self.rate = seconds / samples
            self.last_samples = samples

    def region(self, start: int, width: int, height: int, spp: int) -> tuple[int, int]:
        """The next pixel run from pixel ``start`` of a ``width`` x ``height`` frame: whole lines
        from a line's start, else (a line is more than a turn, or ``start`` is inside a line)
        a run to at most the end of ``start``'s line."""
        pixels = max(1, self.samples() // max(1, spp))
        total = width * height
        if start % width == 0 and pixels >= width:
            return start, min(total, start + (pixels // width) * width)
        line_end = (start // width + 1) * width
        return start, min(line_end, start + pixels)


class TurnedFrame:
    """One resolved request (camera and settings given) rendered run by run; ``turns`` is the
    generator that renders it, yielding before every run (after the first)."""

    def __init__(self, request: FrameRequest, sizer: TurnSizer) -> None:
        self.request = request
        self.sizer = sizer
        self.width, self.height = request.camera.width, request.camera.height
        self.pixels = np.zeros((self.width * self.height, 3), np.float32)
        self.aov_pixels = (
            np.zeros((self.width * self.height, CHANNELS), np.float32)
            if request.settings.renders_aovs
            else None
        )
        self.pixels_done = 0
        self.work = 0.0
        """The kernels' work count of every run so far."""
        self.seconds = 0.0
        """Seconds the runs took (the coordinator's, not the caller's other turns)."""

    @property
    def image(self) -> np.ndarray:
        """float32 (H, W, 3)."""
        return self.pixels.reshape(self.height, self.width, 3)

    @property
    def aov(self) -> np.ndarray | None:
        """float32 (H, W, ``aov.CHANNELS``) when the settings render AOVs, else None."""
        if self.aov_pixels is None:
            return None
        return self.aov_pixels.reshape(self.height, self.width, CHANNELS)

    @property
    def samples_done(self) -> int:
        return self.pixels_done * self.request.settings.spp

    def turns(
        self, coordinator, graph, on_run: Callable[[Frame], None] | None = None
    ) -> Generator[None, None, None]:
        """Render the runs on ``graph``; ``on_run`` sees the coordinator's frame of each."""
        total = self.width * self.height
        spp = self.request.settings.spp
        while self.pixels_done < total:
            r0, r1 = self.sizer.region(self.pixels_done, self.width, self.height, spp)
            if self.pixels_done:
                yield
            whole = r0 == 0 and r1 == total
            run = replace(self.request, region=None if whole else (r0, r1))
            frame = coordinator.render_frame(run, graph)
            self.pixels[r0:r1] = frame.rgb.reshape(-1, 3)
            if self.aov_pixels is not None:
                self.aov_pixels[r0:r1] = frame.aov.reshape(-1, CHANNELS)
            self.work += float(frame.cost.sum())
            self.seconds += frame.wall_seconds
            self.sizer.observe((r1 - r0) * spp, frame.wall_seconds)
            self.pixels_done = r1
            if on_run is not None:
                on_run(frame)


def spot_checks_in_turns(
    coordinator, checks: SpotCheck, request: FrameRequest, graph, sizer: TurnSizer
) -> Generator[None, None, tuple[np.ndarray, np.ndarray, np.ndarray, float]]:
    """``coordinator.render_spot_checks`` in runs of pixels sized like turns, yielding before
    every run after the first; returns its ``(pixels, parts, work)`` and the seconds taken."""
    samples = PARTS * np.asarray(checks.part_spp, np.int64)
    outs, seconds, start = [], 0.0, 0
    while True:
        taken = np.cumsum(samples[start:])
        end = min(len(samples), start + max(1, int(np.searchsorted(taken, sizer.samples()))))
        if outs:
            yield
        rows = slice(start, end)
        t0 = time.perf_counter()
        outs.append(
            coordinator.render_spot_checks(
                SpotCheck(checks.pixels[rows], checks.part_start[rows], checks.part_spp[rows]),
                request,
                graph,
            )
        )
        dt = time.perf_counter() - t0
        sizer.observe(int(samples[rows].sum()), dt)
        seconds += dt
        start = end
        if start >= len(samples):
            break
    pixels, parts, work = zip(*outs, strict=True)
    return np.concatenate(pixels), np.concatenate(parts, axis=1), np.concatenate(work), seconds

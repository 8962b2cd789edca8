"""A job as the render thread renders it: its frames, its scene with the request's overrides,
and one bounded turn (``cluster.turns``) per step.
"""

import concurrent.futures
import dataclasses
import functools
import time
from collections.abc import Callable, Generator
from pathlib import Path

import numpy as np

from api.settings import Settings
from cluster.jobs import quality_goal, with_overrides
from cluster.progressive import DenoisedTarget, ProgressiveFrame, part_request
from cluster.scene_graph import SceneGraph
from cluster.turns import TurnedFrame, TurnSizer, spot_checks_in_turns
from tracer.accuracy.spot_check import SpotCheck
from tracer.io.metadata import id_names
from tracer.post.frame_layers import frame_layers
from tracer.request import FrameRequest
from tracer.scene import format as fmt
from tracer.scene.model import SceneState


def job_dir(settings: Settings, job_id: str) -> Path:
    return settings.data_dir / "jobs" / job_id


@dataclasses.dataclass
class FrameSpec:
    number: int
    camera: fmt.Camera | None
    """None: the state's camera at that frame (a still, or the scene's keyframes)."""


def job_frames(state: SceneState, request: dict) -> list[FrameSpec]:
    """The frames a job request renders (already validated against the state)."""
    kind = request.get("kind", "still")
    if kind == "still":
        pose = request.get("camera")
        if pose:
            changes = {k: v for k, v in pose.items() if v is not None}
            return [FrameSpec(0, fmt.override(state.camera, **changes))]
        return [FrameSpec(0, None)]
    path = request.get("camera_path")
    if path:
        return [
            FrameSpec(
                i, fmt.override(state.camera, **{k: v for k, v in pose.items() if v is not None})
            )
            for i, pose in enumerate(path)
        ]
    frames = request.get("frames")
    if frames is None:
        frames = list(range(state.animation.frames if state.animation is not None else 1))
    return [FrameSpec(int(n), None) for n in frames]


def job_state(state: SceneState, request: dict) -> SceneState:
    """The scene as the job renders it: the request's overrides applied to the state by the
    rule ``tilerender render`` applies its flags by (SceneError for a value out of range)."""
    return with_overrides(
        state,
        width=request.get("width"),
        height=request.get("height"),
        spp=request.get("spp"),
        seed=request.get("seed"),
        max_depth=request.get("max_depth"),
        kernel=request.get("kernel"),
        light_sampler=request.get("light_sampler"),
        aovs=request.get("aovs"),
        denoise=request.get("denoise"),
        denoise_prefilter=request.get("denoise_prefilter"),
        adaptive=request.get("adaptive"),
    )


WAIT_SECONDS = 0.05
"""Longest a turn waits for a wave's arithmetic on the worker thread before giving way."""


@functools.cache
def wave_worker() -> concurrent.futures.ThreadPoolExecutor:
    """The one thread progressive frames' arithmetic runs on."""
    return concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="tilerender-waves")


def off_thread(fn: Callable, *args) -> Generator:
    """``fn(*args)`` on the wave worker thread, yielding turns (each waiting at most
    ``WAIT_SECONDS``) until it returns: a progressive frame's estimate and spot-check plan at
    4K take seconds of numpy (which releases the GIL), and the render thread keeps serving
    sessions and calls meanwhile. Returns what ``fn`` returns."""
    future = wave_worker().submit(fn, *args)
    while True:
        try:
            return future.result(timeout=WAIT_SECONDS)
        except concurrent.futures.TimeoutError:
            yield


class JobRun:
    """A job being rendered by the render thread, one bounded turn per :meth:`step`.

    A turn renders one pixel run of a frame (about ``sizer.seconds`` of work, the whole frame
    when it is smaller) or one run of a progressive wave's spot checks. A frame by samples per
    pixel is one pass, run by run, so its pixels are the command line's bit for bit; a
    progressive frame's clock counts only this job's turns (not other work in between).
    """

    def __init__(
        self,
        record: dict,
        state: SceneState,
        done_frames: set[int],
        settings: Settings,
    ):
        self.id = record["id"]
        self.record = record
        self.request = record["request"]
        self.settings = settings
        self.base = job_state(state, self.request)
        self.graph = SceneGraph(self.base, key=self.id)
        self.frames = job_frames(self.base, self.request)
        self.todo = [f for f in self.frames if f.number not in done_frames]
        self.done = len(self.frames) - len(self.todo)
        self.keyframes = self.request.get("kind") == "animation" and not self.request.get(
            "camera_path"
        )
        target, budget = self.request.get("target_error"), self.request.get("time_budget")
        self.mode = (
            "target_error" if target is not None else "time_budget" if budget is not None else "spp"
        )
        self.width, self.height = self.base.camera.width, self.base.camera.height
        self.spp = self.base.render.spp
        self.max_spp = min(self.request.get("max_spp") or settings.max_spp, settings.max_spp)
        self.goal = quality_goal(
            None if target is None else float(target),
            None if budget is None else float(budget),
            self.max_spp,
            len(self.frames),
        )
        self.sizer = TurnSizer(settings.job_turn_seconds)
        """Sizes the turns; the service sets its ``seconds`` before each."""
        self.started = time.monotonic()
        self.done_at_start = self.done
        self.last_frame = None
        """The coordinator's ``Frame`` of the latest turn (the service records it)."""
        self.progressive: ProgressiveFrame | None = None
        self.current: FrameSpec | None = None
        self.current_started = 0.0
        """The job's own seconds when the current frame started."""
        self.part: TurnedFrame | None = None
        """The frame, or progressive part, being rendered."""
        self.samples_finished = 0
        """Samples of every finished frame and part."""
        self._work: Generator | None = None

    @property
    def finished(self) -> bool:
        return not self.todo and self.current is None

    @property
    def samples_done(self) -> int:
        part = self.part
        return self.samples_finished + (0 if part is None else part.samples_done)

    def step(self, coordinator) -> tuple[FrameSpec, dict[str, np.ndarray], dict] | None:
        """Render one turn; returns (frame, layers, info) when that turn finished a frame:
        its layers by name (``tracer.post.frame_layers``), info its spp, error estimate (and,
        for a progressive frame, ``error_of``: which image it is of), seconds, the denoiser's
        report and what the id layers name (``id_names``)."""
        if self._work is None:
            self.current = self.todo[0]
            self.current_started = self.sizer.seconds_total
            if self.keyframes:
                self.graph.frame_commit(self.current.number)
            self._work = self._frame(coordinator, self.current)
            next(self._work)  # up to its first turn
        try:
            next(self._work)
            return None
        except StopIteration as finished:
            self._work = None
            return finished.value

    def close(self) -> None:
        """Stop rendering (a cancel): the turn that ran last was the last."""
        if self._work is not None:
            self._work.close()
            self._work = None

    def _frame(self, coordinator, spec: FrameSpec) -> Generator:
        """Frame ``spec``'s turns, a yield before each; returns (frame, layers, info)."""
        state = self.graph.state
        request = FrameRequest(spec.number, spec.camera or state.camera, state.render)
        yield
        if self.goal is None:
            part = yield from self._part(coordinator, request)
            layers, made = yield from off_thread(
                frame_layers, part.image, part.aov, request.settings
            )
            return self._complete(spec, layers, made, request.spp, None, part.seconds)
        camera = request.camera
        sizer = self.sizer
        p = self.progressive = ProgressiveFrame(
            camera.width,
            camera.height,
            self.goal,
            clock=lambda: sizer.seconds_total,
            denoised=DenoisedTarget.of(request.settings, self.goal),
            adaptive=request.settings.adaptive,
        )
        step = p.next_part()
        while step is not None:
            if isinstance(step, SpotCheck):
                checks = spot_checks_in_turns(coordinator, step, request, self.graph, sizer)
                pixels, parts, work, seconds = yield from checks
                yield from off_thread(p.add_spot_checks, pixels, parts, seconds, work)
            else:
                part = yield from self._part(coordinator, part_request(request, step))
                yield from off_thread(p.add_part, part.image, part.seconds, part.work, part.aov)
            step = p.next_part()
            if step is not None:
                yield
        layers, made = yield from off_thread(lambda: frame_layers(p.image, p.aov, request.settings))
        summary = p.summary()
        made = {**made, **{k: summary[k] for k in ("error_of", "mean_spp", "adaptive_waves")}}
        return self._complete(spec, layers, made, p.spp, p.error, p.elapsed)

    def _part(self, coordinator, request: FrameRequest) -> Generator:
        """Render ``request`` run by run; returns its :class:`TurnedFrame`."""
        part = self.part = TurnedFrame(request, self.sizer)
        yield from part.turns(coordinator, self.graph, self._ran)
        self.samples_finished += part.samples_done
        self.part = None
        return part

    def _ran(self, frame) -> None:
        self.last_frame = frame

    def _complete(self, spec, layers, made, spp, error, seconds):
        self.todo.pop(0)
        self.current = None
        self.progressive = None
        self.done += 1
        info = {"spp": spp, "error_estimate": error, "seconds": seconds, **made}
        return spec, layers, {**info, **id_names(self.base, self.base.render)}

    def progress(self) -> dict:
        """Frames, lines, samples and an ETA, from what the thread has recorded (any thread)."""
        total = len(self.frames)
        part = self.part
        lines_done = 0 if part is None else part.pixels_done // part.width
        p = self.progressive
        spp_current = p.spp if p is not None else 0
        elapsed = time.monotonic() - self.started
        eta = None
        if self.mode == "spp":
            per_frame = self.width * self.height * self.spp
            pixels_done = 0 if part is None else part.pixels_done
            done_work = (self.done - self.done_at_start) * per_frame + pixels_done * self.spp
            remaining = (total - self.done) * per_frame - pixels_done * self.spp
            if done_work > 0:
                eta = elapsed / done_work * max(0, remaining)
        elif self.mode == "time_budget":
            frame_own = self.sizer.seconds_total - self.current_started if self.current else 0.0
            eta = max(0.0, (total - self.done) * self.goal.time_budget - frame_own)
        elif p is not None and p.waves and p.waves[-1].error and self.done == self.done_at_start:
            target = float(self.request["target_error"])
            wave = p.waves[-1]  # the estimate and the samples it was made at
            # Mean samples per pixel: what max_spp bounds (the range exceeds it when adaptive).
            needed = min(self.max_spp, wave.mean_spp * (wave.error / target) ** 2)
            taken = p.mean_spp
            eta = p.elapsed / taken * max(0.0, needed - taken) * (total - self.done)
        elif self.done > self.done_at_start:
            eta = elapsed / (self.done - self.done_at_start) * (total - self.done)
        return {
            "frames_done": self.done,
            "frames_total": total,
            "current_frame": None if self.current is None else self.current.number,
            "lines_done": lines_done,
            "lines_total": self.height,
            "samples_done": self.samples_done,
            "spp_current_frame": spp_current if self.mode != "spp" else self.spp,
            "error_estimate": None if p is None else p.error,
            "error_spp": p.waves[-1].spp if p is not None and p.waves else None,
            "eta_seconds": None if eta is None else round(eta, 3),
            "elapsed_seconds": round(elapsed, 3),
        }

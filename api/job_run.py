"""A job as the render thread renders it: its frames, its scene with the request's overrides,
and one coordinator frame (a whole frame, or one part of a progressive frame's wave) per step.
"""

import dataclasses
import time
from pathlib import Path

import numpy as np

from api.settings import Settings
from cluster.jobs import quality_goal, with_overrides
from cluster.progressive import ProgressiveFrame, progressive_step
from cluster.scene_graph import SceneGraph
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
    )


class JobRun:
    """A job being rendered by the render thread, one coordinator frame per :meth:`step`."""

    def __init__(self, record: dict, state: SceneState, done_frames: set[int], settings: Settings):
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
        self.started = time.monotonic()
        self.done_at_start = self.done
        self.inflight = None
        self.last_frame = None
        self.progressive: ProgressiveFrame | None = None
        self.current: FrameSpec | None = None
        self.current_started = 0.0
        self.samples_done = 0

    @property
    def finished(self) -> bool:
        return not self.todo and self.current is None

    def step(self, coordinator) -> tuple[FrameSpec, np.ndarray, dict] | None:
        """Render one coordinator frame; returns (frame, image, info) when a frame is done."""
        if self.current is None:
            self.current = self.todo[0]
            self.current_started = time.monotonic()
            if self.keyframes:
                self.graph.frame_commit(self.current.number)
        spec = self.current
        state = self.graph.state
        request = FrameRequest(spec.number, spec.camera or state.camera, state.render)

        def render(request: FrameRequest):
            self.inflight = coordinator.submit_frame(request, self.graph)
            try:
                frame = coordinator.wait_frame(self.inflight)
            finally:
                self.inflight = None
            self.last_frame = frame
            self.samples_done += request.camera.width * request.camera.height * request.spp
            return frame

        if self.goal is None:
            frame = render(request)
            return self._complete(spec, frame.rgb, request.spp, None, frame.wall_seconds)
        # One part of a wave (four independent parts per wave, whose spread estimates the
        # error of their mean), or a wave's spot checks.
        p = self.progressive
        if p is None:
            camera = request.camera
            p = self.progressive = ProgressiveFrame(camera.width, camera.height, self.goal)
        progressive_step(coordinator, p, request, self.graph, render)
        if not p.done:
            return None
        return self._complete(spec, p.image, p.spp, p.error, p.elapsed)

    def _complete(self, spec, image, spp, error, seconds):
        self.todo.pop(0)
        self.current = None
        self.progressive = None
        self.done += 1
        return spec, image, {"spp": spp, "error_estimate": error, "seconds": seconds}

    def progress(self) -> dict:
        """Frames, lines, samples and an ETA, from what the thread has recorded (any thread)."""
        total = len(self.frames)
        lines_done = 0
        inflight = self.inflight
        if inflight is not None:
            try:
                lines_done = int(inflight.assembler.done.sum())
            except AttributeError:  # pragma: no cover - a coordinator without an assembler
                lines_done = 0
        p = self.progressive
        spp_current = p.spp if p is not None else 0
        elapsed = time.monotonic() - self.started
        eta = None
        if self.mode == "spp":
            per_frame = self.width * self.height * self.spp
            done_work = (
                self.done - self.done_at_start
            ) * per_frame + lines_done * self.width * self.spp
            remaining = (total - self.done) * per_frame - lines_done * self.width * self.spp
            if done_work > 0:
                eta = elapsed / done_work * max(0, remaining)
        elif self.mode == "time_budget":
            frame_elapsed = time.monotonic() - self.current_started if self.current else 0.0
            eta = max(0.0, (total - self.done) * self.goal.time_budget - frame_elapsed)
        elif p is not None and p.waves and p.waves[-1].error and self.done == self.done_at_start:
            target = float(self.request["target_error"])
            wave = p.waves[-1]  # the estimate and the samples it was made at
            needed = min(self.max_spp, wave.spp * (wave.error / target) ** 2)
            eta = p.elapsed / p.spp * max(0.0, needed - p.spp) * (total - self.done)
        elif self.done > self.done_at_start:
            eta = elapsed / (self.done - self.done_at_start) * (total - self.done)
        return {
            "frames_done": self.done,
            "frames_total": total,
            "current_frame": None if self.current is None else self.current.number,
            "lines_done": lines_done if self.mode == "spp" else (self.height if p else 0),
            "lines_total": self.height,
            "samples_done": self.samples_done,
            "spp_current_frame": spp_current if self.mode != "spp" else self.spp,
            "error_estimate": None if p is None else p.error,
            "error_spp": p.waves[-1].spp if p is not None and p.waves else None,
            "eta_seconds": None if eta is None else round(eta, 3),
            "elapsed_seconds": round(elapsed, 3),
        }

"""The render service: one thread owns the coordinator; jobs, sessions and calls take turns.

The coordinator is not thread-safe, so exactly one thread, ``tilerender-render``, creates it,
drives it and closes it. The event loop never waits for it: endpoints read job state from
SQLite and from the small in-memory progress records this thread updates, and the few
operations that need the coordinator itself (a ray query, a balancer switch, opening a
session) are *calls*: a function queued for the thread, whose result the endpoint awaits as a
future while the loop serves everyone else.

**Turns.** Each pass of the thread's loop first runs every queued call, then gives one *turn*
to the next in a round-robin over the running job (at most one job runs at a time, in
submission order) and every watched session. A session's turn is one
``InteractiveSession.render_next()``; a job's turn is one coordinator frame: a whole frame
for a job by samples per pixel (rendered in one pass, so the result is bit-identical to the
command line's), or one part of a wave of a progressive frame for a job by target error or
time budget. So a session waits at most one job frame between two of its own frames, and a job
advances at least once per round. Sessions nobody watches (no stream client and no request
for ``session_render_grace`` seconds) are skipped; idle ones expire.

**Graphs.** The thread names the graph of whatever it renders next in each coordinator call;
tracers keep replicas of the few most recently used graphs (by key), so taking turns between
scenes costs a snapshot only for a scene a tracer does not hold. A job renders a private graph
(keyed by the job's id) made from the scene's state when it was submitted (saved beside its
results), so later commits to the scene never change a job, and an animation's pose commits
never touch the scene.

**Restart.** Jobs, their state snapshots and each finished frame are on disk before they are
reported. At start, ``running`` and ``queued`` jobs are queued again and resume at their first
frame without a result (``resume_jobs``), or are marked ``failed`` with the reason.
"""

import asyncio
import collections
import concurrent.futures
import dataclasses
import gc
import io
import logging
import os
import signal
import threading
import time
import traceback
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from api.events import EventHub
from api.scenes import SceneEntry, SceneRepository, _write_atomic
from api.settings import Settings
from api.store import TERMINAL, Store
from cluster.progressive import Goal, ProgressiveFrame, SpotCheck
from cluster.scene_graph import SceneGraph
from tracer.errors import SceneError
from tracer.io.images import linear_to_srgb8, write_image
from tracer.request import FrameRequest
from tracer.scene import format as fmt
from tracer.scene.codec import decode_state, encode_state
from tracer.scene.model import SceneState

log = logging.getLogger("tilerender.api")

SESSION_RENDER_GRACE = 10.0
"""Seconds a session keeps rendering after its last request when no stream is open."""
NODE_RESCAN_SECONDS = 5.0
"""How often the render thread looks for Ray nodes without a tracer (nodes that joined)."""


def job_dir(settings: Settings, job_id: str) -> Path:
    return settings.data_dir / "jobs" / job_id


# --- Jobs --------------------------------------------------------------------------------------


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
    """The scene as the job renders it: the request's overrides of camera and settings applied
    to the state (exactly what ``tilerender render`` does with its flags)."""
    camera = fmt.override(state.camera, width=request.get("width"), height=request.get("height"))
    render = fmt.override(
        state.render,
        spp=request.get("spp"),
        seed=request.get("seed"),
        max_depth=request.get("max_depth"),
    )
    return dataclasses.replace(state, camera=camera, render=render)


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
        self.mode = (
            "target_error"
            if self.request.get("target_error") is not None
            else "time_budget"
            if self.request.get("time_budget") is not None
            else "spp"
        )
        self.width, self.height = self.base.camera.width, self.base.camera.height
        self.spp = self.base.render.spp
        self.max_spp = min(self.request.get("max_spp") or settings.max_spp, settings.max_spp)
        self.started = time.monotonic()
        self.done_at_start = self.done
        self.inflight = None
        self.last_frame = None
        self.progressive: ProgressiveFrame | None = None
        self.current: FrameSpec | None = None
        self.current_started = 0.0
        self.samples_done = 0
        self.frame_budget = (
            float(self.request["time_budget"]) / max(1, len(self.frames))
            if self.mode == "time_budget"
            else None
        )

    @property
    def finished(self) -> bool:
        return not self.todo and self.current is None

    def _camera_settings(self, spec: FrameSpec):
        state = self.graph.state
        camera = spec.camera or state.camera
        return camera, state.render

    def step(self, coordinator) -> tuple[FrameSpec, np.ndarray, dict] | None:
        """Render one coordinator frame; returns (frame, image, info) when a frame is done."""
        if self.current is None:
            self.current = self.todo[0]
            self.current_started = time.monotonic()
            if self.keyframes:
                self.graph.frame_commit(self.current.number)
        spec = self.current
        camera, render = self._camera_settings(spec)
        if self.mode == "spp":
            self.inflight = coordinator.submit_frame(
                FrameRequest(spec.number, camera, render, 0), self.graph
            )
            try:
                frame = coordinator.wait_frame(self.inflight)
            finally:
                self.inflight = None
            self.last_frame = frame
            self.samples_done += camera.width * camera.height * render.spp
            return self._complete(spec, frame.rgb, render.spp, None, frame.wall_seconds)
        return self._wave(coordinator, spec, camera, render)

    def _wave(self, coordinator, spec: FrameSpec, camera, render):
        """One part of a wave of a progressive frame (``cluster.progressive``: four independent
        parts per wave, whose spread estimates the error of their mean)."""
        p = self.progressive
        if p is None:
            target = self.request.get("target_error")
            goal = Goal(
                target_error=None if target is None else float(target),
                time_budget=self.frame_budget,
                max_spp=self.max_spp,
            )
            p = self.progressive = ProgressiveFrame(camera.width, camera.height, goal)
        part = p.next_part()
        t0 = time.monotonic()
        if isinstance(part, SpotCheck):
            pixels, parts, work = coordinator.render_spot_checks(
                part, FrameRequest(spec.number, camera, render), self.graph
            )
            p.add_spot_checks(pixels, parts, time.monotonic() - t0, work)
        else:
            self.inflight = coordinator.submit_frame(
                FrameRequest(
                    spec.number, camera, fmt.override(render, spp=part.spp), part.sample_start
                ),
                self.graph,
            )
            try:
                frame = coordinator.wait_frame(self.inflight)
            finally:
                self.inflight = None
            self.last_frame = frame
            p.add_part(frame.rgb, time.monotonic() - t0, float(frame.cost.sum()))
            self.samples_done += camera.width * camera.height * part.spp
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
            eta = max(0.0, (total - self.done) * self.frame_budget - frame_elapsed)
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


# --- Sessions ----------------------------------------------------------------------------------


class LiveSession:
    """An interactive session as the service holds it: the cluster's
    :class:`InteractiveSession`, the latest JPEG frame, its watchers and timings."""

    def __init__(self, session_id: str, entry: SceneEntry, width: int, height: int, loop):
        self.id = session_id
        self.scene_id = entry.id
        self.entry = entry
        self.width, self.height = width, height
        self.loop = loop
        self.session = None
        self.camera: fmt.Camera | None = None
        self.created = time.time()
        self.last_activity = time.monotonic()
        self.clients = 0
        self.seq = 0
        self.jpeg: bytes | None = None
        self.meta: dict = {}
        self.closed = False
        self.closed_reason: str | None = None
        self.error: str | None = None
        self.event = asyncio.Event()
        self.camera_update_at: float | None = None
        self.latencies: collections.deque = collections.deque(maxlen=64)
        self.overheads: collections.deque = collections.deque(maxlen=64)
        self.encode_ms: collections.deque = collections.deque(maxlen=64)
        self.render_ms: collections.deque = collections.deque(maxlen=64)
        self.last_render_end: float | None = None
        self.frame_times: collections.deque = collections.deque(maxlen=32)
        self.frames = 0

    def touch(self) -> None:
        self.last_activity = time.monotonic()

    def watched(self, now: float) -> bool:
        return self.clients > 0 or now - self.last_activity < SESSION_RENDER_GRACE

    def publish(self, jpeg: bytes, meta: dict) -> None:
        """Runs on the event loop: store the frame and wake the streams."""
        self.jpeg, self.meta = jpeg, meta
        self.seq += 1
        event, self.event = self.event, asyncio.Event()
        event.set()

    def wake(self) -> None:
        """Runs on the event loop: wake the streams (the session closed)."""
        event, self.event = self.event, asyncio.Event()
        event.set()

    def stats(self) -> dict:
        base: dict = {}
        if self.session is not None:
            try:
                base = dict(self.session.stats())
            except Exception:
                base = {}

        def mean(values):
            return round(float(np.mean(values)), 3) if values else None

        times = list(self.frame_times)
        fps = (
            (len(times) - 1) / (times[-1] - times[0])
            if len(times) > 1 and times[-1] > times[0]
            else None
        )
        return {
            **{k: _plain(v) for k, v in base.items()},
            "fps_stream": None if fps is None else round(fps, 2),
            "frames_streamed": self.seq,
            "clients": self.clients,
            "last_frame": self.meta,
            "camera_latency_ms": mean(self.latencies),
            "camera_latency_last_ms": self.latencies[-1] if self.latencies else None,
            "api_overhead_ms": mean(self.overheads),
            "render_ms": mean(self.render_ms),
            "api_overhead_percent": None
            if not self.overheads or not self.render_ms
            else round(100 * float(np.mean(self.overheads)) / float(np.mean(self.render_ms)), 3),
            "encode_ms": mean(self.encode_ms),
        }


def _plain(value):
    if isinstance(value, np.generic):
        return value.item()
    return value


def encode_jpeg(image: np.ndarray, quality: int) -> bytes:
    """Float32 linear HxWx3 -> sRGB JPEG bytes."""
    from PIL import Image

    buffer = io.BytesIO()
    Image.fromarray(linear_to_srgb8(image), mode="RGB").save(
        buffer, format="JPEG", quality=quality, subsampling=0
    )  # 4:4:4: noisy, converging renders keep their colours
    return buffer.getvalue()


def session_factory_for(settings: Settings) -> Callable[[], type]:
    """The class ``settings.session_class`` names (``module:Class``), imported on first use:
    ``cluster.session.InteractiveSession`` by default."""

    def factory() -> type:
        import importlib

        module, _, name = settings.session_class.partition(":")
        return getattr(importlib.import_module(module), name)

    return factory


def warm_state() -> SceneState:
    """A one-quad scene the coordinator starts with (tracers need a scene to come up)."""
    from tracer.scene.loader import scene_from_file_model

    scene = fmt.SceneFile.model_validate(
        {
            "camera": {"width": 4, "height": 4},
            "render": {"spp": 1},
            "materials": {"light": {"emission": [1, 1, 1]}},
            "objects": [{"shape": {"type": "rectangle"}, "material": "light"}],
        }
    )
    return scene_from_file_model(scene, Path("."))


# --- The service -------------------------------------------------------------------------------


class RenderService:
    """Owns the render thread and everything it renders (see the module docstring)."""

    def __init__(
        self,
        settings: Settings,
        store: Store,
        scenes: SceneRepository,
        events: EventHub,
        metrics=None,
        session_factory: Callable[[], type] | None = None,
    ) -> None:
        self.settings = settings
        self.store = store
        self.scenes = scenes
        self.events = events
        self.metrics = metrics
        self.session_factory = session_factory or session_factory_for(settings)
        self.loop: asyncio.AbstractEventLoop | None = None
        self._sigterm = None
        self.coordinator = None
        self.connection = None
        self.ready = False
        self.error: str | None = None
        self.started_at = time.time()
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._wake = threading.Condition()
        self._calls: collections.deque = collections.deque()
        self._queue: collections.deque[str] = collections.deque()
        self._cancelled: set[str] = set()
        self.run: JobRun | None = None
        self.sessions: dict[str, LiveSession] = {}
        self._turn = 0
        self._previous = None
        self._reniced: set[int] = set()
        self._node: str | None = None
        self._rescanned = 0.0
        self._encoder = concurrent.futures.ThreadPoolExecutor(
            1, thread_name_prefix="tilerender-encode"
        )
        self.cluster_info: dict = {"tracers": [], "last_frame": None}
        self.frames_rendered = 0

    # Lifecycle ---------------------------------------------------------------------------------

    def start(self, loop: asyncio.AbstractEventLoop) -> None:
        self.loop = loop
        # Ray's core installs its own SIGTERM handler when it starts (it prints a stack and
        # exits at once); the server's handler (a graceful shutdown) is put back afterwards.
        self._sigterm = signal.getsignal(signal.SIGTERM)
        self._recover_jobs()
        self._thread = threading.Thread(target=self._main, name="tilerender-render", daemon=True)
        self._thread.start()

    def stop(self, timeout: float = 30.0) -> None:
        self._stop.set()
        self._notify()
        if self._thread is not None:
            self._thread.join(timeout)
        self._encoder.shutdown(wait=False, cancel_futures=True)

    def _notify(self) -> None:
        with self._wake:
            self._wake.notify_all()

    def _recover_jobs(self) -> None:
        """Queue unfinished jobs again (or fail them, with the reason)."""
        for record in self.store.unfinished_jobs():
            if not self.settings.resume_jobs:
                reason = "the service restarted while the job was unfinished (resume_jobs is off)"
                self._fail(record["id"], reason)
                continue
            snapshot = job_dir(self.settings, record["id"]) / "scene.tls"
            if not snapshot.is_file():
                self._fail(
                    record["id"], "the service restarted and the job's scene snapshot is missing"
                )
                continue
            self.store.update_job(record["id"], status="queued", resumed=record["resumed"] + 1)
            self._queue.append(record["id"])
            log.info(
                "job %s queued again after a restart (%d frames done)",
                record["id"],
                record["frames_done"],
            )

    def _fail(self, job_id: str, reason: str) -> None:
        if self.store.finish_job(job_id, "failed", reason):
            self._count_job("failed")
            self.events.publish(
                job_id, "error", {"job": job_id, "status": "failed", "message": reason}
            )

    def _main(self) -> None:
        try:
            self._start_cluster()
        except BaseException as exc:
            reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            self.error = f"the cluster did not start: {reason}"
            log.error("%s", self.error)
            while not self._stop.is_set():  # answer calls with the error
                self._run_calls()
                with self._wake:
                    self._wake.wait(0.2)
            return
        # Everything imported and built so far lives as long as the process: keep it out of
        # the garbage collector's full passes, which otherwise pause every thread (the event
        # loop too) for tens of milliseconds on this many objects.
        gc.collect()
        gc.freeze()
        self.ready = True
        try:
            while not self._stop.is_set():
                self._run_calls()
                self._expire_sessions()
                self._place_new_nodes()
                try:
                    worked = self._turn_once()
                except Exception as exc:  # a bug or a full disk: fail the work, keep serving
                    log.exception("render thread: unexpected error")
                    worked = True
                    if self.run is not None:
                        run, self.run = self.run, None
                        self._fail(run.id, f"internal error: {exc}")
                if not worked:
                    with self._wake:
                        if not self._calls and not self._stop.is_set():
                            self._wake.wait(0.1)
        finally:
            self.ready = False
            self._shutdown_cluster()

    def _start_cluster(self) -> None:
        from cluster.connect import connect
        from cluster.coordinator import Coordinator

        num_cpus = self.settings.num_cpus if self.settings.ray_address is None else None
        self.connection = connect(self.settings.ray_address, num_cpus=num_cpus)
        if callable(self._sigterm) and self.loop is not None:
            self.loop.call_soon_threadsafe(signal.signal, signal.SIGTERM, self._sigterm)
        import ray

        self._node = ray.get_runtime_context().get_node_id()
        self.warm = SceneGraph(warm_state(), key="warm")
        self.coordinator = Coordinator(
            self.warm,
            tracers=self.settings.tracers,
            cpus_per_tracer=self.settings.threads,
            balancer=self.settings.balancer,
        )
        self._refresh_cluster_info()

    def _shutdown_cluster(self) -> None:
        for live in list(self.sessions.values()):
            self._close_session(live, "the service is stopping")
        if self.coordinator is not None:
            try:
                self.coordinator.close()
            except Exception:
                log.exception("closing the coordinator")
        if self.connection is not None and self.connection.started:
            from cluster.connect import disconnect

            disconnect()

    # Calls -------------------------------------------------------------------------------------

    def call(self, fn: Callable[[Any], Any]) -> concurrent.futures.Future:
        """Run ``fn(coordinator)`` on the render thread before its next turn."""
        future: concurrent.futures.Future = concurrent.futures.Future()
        self._calls.append((fn, future))
        self._notify()
        return future

    async def call_async(self, fn: Callable[[Any], Any], timeout: float | None = None):
        return await asyncio.wait_for(asyncio.wrap_future(self.call(fn)), timeout)

    def _run_calls(self) -> None:
        while self._calls:
            fn, future = self._calls.popleft()
            if not future.set_running_or_notify_cancel():
                continue
            if self.coordinator is None:
                future.set_exception(RuntimeError(self.error or "the cluster is not ready yet"))
                continue
            try:
                future.set_result(fn(self.coordinator))
            except BaseException as exc:
                future.set_exception(exc)

    # Turns -------------------------------------------------------------------------------------

    def _turn_once(self) -> bool:
        """Give one turn to the next job or watched session; False if nothing wanted one."""
        now = time.monotonic()
        workers: list = []
        if self.run is None:
            self._start_next_job()
        if self.run is not None:
            workers.append(self.run)
        workers += [s for s in self.live_sessions() if s.watched(now)]
        if not workers:
            return False
        self._turn = (self._turn + 1) % len(workers)
        worker = workers[self._turn]
        if isinstance(worker, JobRun):
            self._job_turn(worker)
        else:
            self._session_turn(worker)
        self._previous = worker
        self._refresh_cluster_info()
        return True

    def _place_new_nodes(self) -> None:
        """Every ``NODE_RESCAN_SECONDS``, start tracers on Ray nodes that joined the cluster
        (one tracer per node, the default; a fixed ``tracers`` count is left as it is)."""
        now = time.monotonic()
        if now - self._rescanned < NODE_RESCAN_SECONDS:
            return
        self._rescanned = now
        try:
            started = self.coordinator.place_new_nodes()
        except Exception as exc:  # the GCS briefly unreachable: try again next time
            log.warning("looking for new Ray nodes failed: %s", exc)
            return
        if started:
            log.info("new Ray nodes: started tracers %s", ", ".join(started))
            self._refresh_cluster_info()

    def _refresh_cluster_info(self) -> None:
        try:
            tracers = self.coordinator.tracers()
        except Exception:
            return
        self._renice(tracers)
        self.cluster_info = {
            **self.cluster_info,
            "tracers": tracers,
            "balancer": self.coordinator.balancer_name,
            "stats": dict(getattr(self.coordinator, "stats", {})),
        }

    def _renice(self, tracers: list[dict]) -> None:
        """Lower the CPU priority of tracer processes running on this machine (every thread
        they have; threads they start later inherit it), so that the event loop, which needs
        little CPU but needs it at once, is not queued behind render threads on a machine
        whose every core renders. Tracers on other machines are left alone."""
        nice = self.settings.tracer_nice
        if nice <= 0 or not hasattr(os, "setpriority"):
            return
        for tracer in tracers:
            pid = tracer.get("pid")
            if pid is None or pid in self._reniced or tracer.get("node") != self._node:
                continue
            self._reniced.add(pid)
            try:
                for tid in os.listdir(f"/proc/{pid}/task"):
                    os.setpriority(os.PRIO_PROCESS, int(tid), nice)
            except (OSError, ValueError) as exc:
                log.info(
                    "cannot lower the priority of tracer %s (pid %s): %s", tracer["id"], pid, exc
                )

    def _record_frame(self, frame, kind: str) -> None:
        """Per-tracer lines, speed and idle time of the latest frame, for /v1/cluster."""
        if frame is None:
            return
        lines: dict[str, float] = {}  # in lines: a frame of many tracers hands out spans of them
        for r in frame.ranges:
            lines[r.tracer] = lines.get(r.tracer, 0.0) + frame.units.lines(r.u0, r.u1)
        busy = frame.tracer_seconds
        slowest = max(busy.values(), default=0.0)
        rays = int(frame.rays.sum()) if frame.rays is not None else 0
        per_tracer = {
            tid: {
                "lines": round(lines.get(tid, 0.0), 6),  # exact: spans are powers of two
                "seconds": round(busy.get(tid, 0.0), 6),
                "lines_per_second": round(lines.get(tid, 0) / busy[tid], 2)
                if busy.get(tid)
                else None,
                "idle_percent": round(100.0 * (slowest - busy.get(tid, 0.0)) / slowest, 2)
                if slowest > 0
                else 0.0,
            }
            for tid in set(lines) | set(busy)
        }
        self.cluster_info["last_frame"] = {
            "kind": kind,
            "width": frame.camera.width,
            "height": frame.camera.height,
            "spp": frame.settings.spp,
            "wall_seconds": round(frame.wall_seconds, 6),
            "idle_percent": round(frame.idle_percent, 3),
            "overhead_seconds": round(frame.overhead_seconds, 6),
            "calls": frame.calls,
            "pooled": frame.pooled,
            "rays": rays,
            "mrays_per_second": round(rays / frame.wall_seconds / 1e6, 3)
            if frame.wall_seconds > 0
            else None,
            "tracers": per_tracer,
        }
        self.frames_rendered += 1
        if self.metrics is not None:
            self.metrics.frames.labels(kind).inc()
            self.metrics.frame_seconds.labels(kind).observe(frame.wall_seconds)
            self.metrics.idle.set(frame.idle_percent)
            self.metrics.rays.labels(kind).inc(rays)

    # Jobs --------------------------------------------------------------------------------------

    def submit(self, job_id: str) -> None:
        self._queue.append(job_id)
        self._notify()

    def cancel(self, job_id: str) -> None:
        self._cancelled.add(job_id)
        self._notify()

    def queue_length(self) -> int:
        return len(self._queue) + (1 if self.run is not None else 0)

    def progress(self, job_id: str) -> dict | None:
        run = self.run
        if run is not None and run.id == job_id:
            return run.progress()
        return None

    def _start_next_job(self) -> None:
        while self._queue:
            job_id = self._queue.popleft()
            record = self.store.job(job_id)
            if record is None or record["status"] in TERMINAL or job_id in self._cancelled:
                self._cancelled.discard(job_id)
                continue
            try:
                state = decode_state((job_dir(self.settings, job_id) / "scene.tls").read_bytes())
                done = {f["frame"] for f in self.store.frames(job_id)}
                run = JobRun(record, state, done, self.settings)
            except (OSError, SceneError, ValueError) as exc:
                self._fail(job_id, f"the job cannot start: {exc}")
                continue
            if not self.store.start_job(job_id):  # cancelled since it was read
                self._cancelled.discard(job_id)
                continue
            self.events.publish(
                job_id,
                "status",
                {"job": job_id, "status": "running", "resumed": bool(record["resumed"])},
            )
            self.run = run
            if run.finished:
                self._finish_run(run)
            return

    def _job_turn(self, run: JobRun) -> None:
        if run.id in self._cancelled:
            self._cancelled.discard(run.id)
            self.run = None
            return
        try:
            result = run.step(self.coordinator)
        except Exception as exc:
            log.warning("job %s failed: %s", run.id, exc)
            log.debug("%s", traceback.format_exc())
            self.run = None
            message = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            self._fail(run.id, f"rendering failed: {message}")
            return
        self._record_frame(run.last_frame, "job")
        run.last_frame = None
        if run.id in self._cancelled:  # cancelled while this frame rendered: drop it
            self._cancelled.discard(run.id)
            self.run = None
            return
        if result is None:
            self._publish_progress(run)
            return
        spec, image, info = result
        path = job_dir(self.settings, run.id) / f"frame_{spec.number:06d}.npy"
        write_image(path, image)
        position = next(i for i, f in enumerate(run.frames) if f.number == spec.number)
        self.store.add_frame(
            run.id,
            spec.number,
            position,
            info["spp"],
            info["seconds"],
            path.name,
            info["error_estimate"],
        )
        self.events.publish(
            run.id,
            "frame",
            {
                "job": run.id,
                "frame": spec.number,
                "spp": info["spp"],
                "seconds": round(info["seconds"], 4),
                "error_estimate": info["error_estimate"],
                "url": f"/v1/jobs/{run.id}/frames/{spec.number}",
            },
        )
        self._publish_progress(run)
        if run.finished:
            self._finish_run(run)

    def _publish_progress(self, run: JobRun) -> None:
        self.events.publish(run.id, "progress", {"job": run.id, **run.progress()})

    def _finish_run(self, run: JobRun) -> None:
        self.run = None
        if self.store.finish_job(run.id, "done"):
            self._count_job("done")
            self.events.publish(
                run.id, "done", {"job": run.id, "status": "done", "frames": len(run.frames)}
            )

    def _count_job(self, status: str) -> None:
        if self.metrics is not None:
            self.metrics.jobs.labels(status).inc()

    def save_job_state(self, job_id: str, state: SceneState) -> None:
        """The scene as the job will render it, beside its results (before it is queued)."""
        directory = job_dir(self.settings, job_id)
        directory.mkdir(parents=True, exist_ok=True)
        _write_atomic(directory / "scene.tls", encode_state(state))

    # Queries ---------------------------------------------------------------------------------

    def query_call(self, entry: SceneEntry, origin: np.ndarray, direction: np.ndarray):
        """A call that traces one ray at the scene's current version (a tracer reaches that
        version first, like a render call)."""

        def run(coordinator):
            return coordinator.query(
                origin[None, :],
                direction[None, :],
                graph=entry.graph,
                timeout=self.settings.request_timeout,
            )

        return run

    # Sessions ----------------------------------------------------------------------------------

    def open_session(
        self, live: LiveSession, camera: fmt.Camera, target_fps: float, min_blend: float
    ):
        """On the render thread: make the cluster session and register it."""
        factory = self.session_factory()

        def create(coordinator):
            session = factory(
                coordinator, live.entry.graph, target_fps=target_fps, min_blend=min_blend
            )
            session.set_camera(camera)
            live.session = session
            self.sessions[live.id] = live
            self._gauge_sessions()
            return live

        return create

    def live_sessions(self) -> list[LiveSession]:
        """Open sessions (a copy: the render thread changes the table)."""
        return [live for live in list(self.sessions.values()) if not live.closed]

    def close_session(self, session_id: str, reason: str = "closed") -> bool:
        live = self.sessions.get(session_id)
        if live is None:
            return False
        self.call(lambda _c: self._close_session(live, reason))
        live.closed = True
        return True

    def _close_session(self, live: LiveSession, reason: str) -> None:
        live.closed = True
        live.closed_reason = reason
        self.sessions.pop(live.id, None)
        if live.session is not None:
            try:
                live.session.close()
            except Exception:
                log.exception("closing session %s", live.id)
        if self.loop is not None and not self.loop.is_closed():
            self.loop.call_soon_threadsafe(live.wake)
        self._gauge_sessions()

    def close_scene_sessions(self, scene_id: str) -> None:
        for live in self.live_sessions():
            if live.scene_id == scene_id:
                self.close_session(live.id, "the scene was deleted")

    def _gauge_sessions(self) -> None:
        if self.metrics is not None:
            self.metrics.sessions.set(len(self.sessions))

    def _expire_sessions(self) -> None:
        now = time.monotonic()
        for live in list(self.sessions.values()):
            if live.clients == 0 and now - live.last_activity > self.settings.session_idle_seconds:
                log.info("session %s expired after %.0f s idle", live.id, now - live.last_activity)
                self._close_session(live, "expired")

    def _session_turn(self, live: LiveSession) -> None:
        t0 = time.perf_counter()
        if self._previous is live and live.last_render_end is not None:
            # The render thread's time between two frames of this session: the API's
            # overhead per frame (bookkeeping, hand-off to the encoder, calls, scheduling).
            live.overheads.append(round(1000 * (t0 - live.last_render_end), 3))
        shows_update = live.camera_update_at
        try:
            frame = live.session.render_next()
        except Exception as exc:
            live.error = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            log.warning("session %s failed: %s", live.id, live.error)
            self._close_session(live, live.error)
            return
        t1 = live.last_render_end = time.perf_counter()
        live.render_ms.append(round(1000 * (t1 - t0), 3))
        if shows_update is not None and live.camera_update_at == shows_update:
            live.camera_update_at = None
        meta = {
            "index": int(frame.index),
            "version": int(frame.version),
            "spp": int(frame.spp),
            "width": int(frame.width),
            "height": int(frame.height),
            "blend": float(frame.blend),
            "seconds": round(float(frame.seconds), 5),
            "samples_accumulated": int(frame.samples_accumulated),
        }
        image = frame.image
        quality = self.settings.jpeg_quality
        loop = self.loop

        def encode() -> None:
            e0 = time.perf_counter()
            jpeg = encode_jpeg(image, quality)
            live.encode_ms.append(round(1000 * (time.perf_counter() - e0), 3))
            if loop is None or loop.is_closed():
                return

            def publish() -> None:
                live.publish(jpeg, meta)
                now = time.perf_counter()
                live.frame_times.append(now)
                if shows_update is not None:
                    live.latencies.append(round(1000 * (now - shows_update), 3))

            loop.call_soon_threadsafe(publish)

        self._encoder.submit(encode)
        live.frames += 1
        self._record_frame(getattr(live.session, "last_frame", None), "session")
        if self.metrics is not None and getattr(live.session, "last_frame", None) is None:
            self.metrics.frames.labels("session").inc()
            self.metrics.frame_seconds.labels("session").observe(t1 - t0)


def set_camera_now(live: LiveSession, camera: fmt.Camera) -> None:
    """Thread-safe camera update (InteractiveSession.set_camera is thread-safe)."""
    live.camera_update_at = time.perf_counter()
    live.session.set_camera(camera)
    live.touch()

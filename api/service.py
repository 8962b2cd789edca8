"""The render service: one thread owns the coordinator; jobs, sessions and calls take turns.

The job queue and a job's turns are ``api.job_queue``'s (its steps ``api.job_run``'s), a
session's state ``api.live_session``'s.

The coordinator is not thread-safe, so exactly one thread, ``tilerender-render``, creates it,
drives it and closes it. The event loop never waits for it: endpoints read job state from
SQLite and from the small in-memory progress records this thread updates, and the few
operations that need the coordinator itself (a ray query, a balancer switch, opening a
session) are *calls*: a function queued for the thread, whose result the endpoint awaits as a
future while the loop serves everyone else.

**Turns.** Each pass of the thread's loop first runs every queued call, then gives one *turn*
to the next in a round-robin over the running job (at most one job runs at a time, in
submission order) and every watched session. A session's turn is one
``InteractiveSession.render_next()``; a job's turn is one bounded run of its current frame
(``api.job_run``, ``cluster.turns``: about ``job_turn_seconds`` of work, half that while a
session is watched, whatever the frame's size; its pixels are the same bits as a frame
rendered whole, the command line's). So calls, cancels and sessions wait at most one such
run, and a job advances at least once per round. A cancelled job stops after the run in
progress. Sessions nobody watches (no stream client and
no request for ``session_render_grace`` seconds) are skipped; idle ones expire.

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
import gc
import logging
import signal
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from api.cluster_info import frame_report, renice_local_tracers
from api.errors import ApiError
from api.events import EventHub
from api.job_queue import JobQueue
from api.job_run import JobRun
from api.live_session import LiveSession
from api.scenes import SceneEntry, SceneRepository
from api.settings import Settings
from api.store import Store
from cluster.scene_graph import SceneGraph
from tracer.scene import format as fmt
from tracer.scene.model import SceneState

log = logging.getLogger("tilerender.api")

NODE_RESCAN_SECONDS = 5.0
"""How often the render thread looks for Ray nodes without a tracer (nodes that joined)."""
IDLE_REFRESH_SECONDS = 0.5
"""How often an idle render thread refreshes what /v1/cluster shows (a tracer that died)."""


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
        self.jobs = JobQueue(settings, store, events, metrics, self._notify)
        self.sessions: dict[str, LiveSession] = {}
        self._turn = 0
        self._previous = None
        self._reniced: set[int] = set()
        self._node: str | None = None
        self._rescanned = 0.0
        self.cluster_info: dict = {"tracers": [], "last_frame": None}
        self._cluster_refreshed = 0.0
        self.frames_rendered = 0

    # Lifecycle ---------------------------------------------------------------------------------

    def start(self, loop: asyncio.AbstractEventLoop) -> None:
        self.loop = loop
        # Ray's core installs its own SIGTERM handler when it starts (it prints a stack and
        # exits at once); the server's handler (a graceful shutdown) is put back afterwards.
        self._sigterm = signal.getsignal(signal.SIGTERM)
        self.jobs.recover()
        self._thread = threading.Thread(target=self._main, name="tilerender-render", daemon=True)
        self._thread.start()

    def stop(self, timeout: float = 30.0) -> None:
        self._stop.set()
        self._notify()
        if self._thread is not None:
            self._thread.join(timeout)
        for live in list(self.sessions.values()):
            live.stop_encoder()

    def _notify(self) -> None:
        with self._wake:
            self._wake.notify_all()

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
                    self.jobs.fail_running(f"internal error: {exc}")
                if not worked:
                    if time.monotonic() - self._cluster_refreshed >= IDLE_REFRESH_SECONDS:
                        self._refresh_cluster_info()
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
        run = self.jobs.current()
        sessions = [s for s in self.live_sessions() if s.watched(now)]
        workers: list = ([run] if run is not None else []) + sessions
        if not workers:
            return False
        self._turn = (self._turn + 1) % len(workers)
        worker = workers[self._turn]
        if isinstance(worker, JobRun):
            # Watched sessions share the thread: the job's turns are halved for their latency.
            share = 2.0 if sessions else 1.0
            seconds = self.settings.job_turn_seconds / share
            self.jobs.turn(self.coordinator, seconds, self._record_frame)
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
        self._cluster_refreshed = time.monotonic()
        try:
            tracers = self.coordinator.tracers()
        except Exception:
            return
        renice_local_tracers(tracers, self.settings.tracer_nice, self._node, self._reniced)
        self.cluster_info = {
            **self.cluster_info,
            "tracers": tracers,
            "balancer": self.coordinator.balancer_name,
            "stats": dict(self.coordinator.stats),
        }

    def _record_frame(self, frame, kind: str) -> None:
        """Per-tracer lines, speed and idle time of the latest frame, for /v1/cluster."""
        if frame is None:
            return
        report = self.cluster_info["last_frame"] = frame_report(frame, kind)
        self.frames_rendered += 1
        if self.metrics is not None:
            self.metrics.frames.labels(kind).inc()
            self.metrics.frame_seconds.labels(kind).observe(frame.wall_seconds)
            self.metrics.idle.set(frame.idle_percent)
            self.metrics.rays.labels(kind).inc(report["rays"])

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
        """On the render thread: make the cluster session and register it, if fewer than
        ``max_sessions`` are open (counted on the render thread, the table's one writer, so
        concurrent opens cannot pass the limit together)."""
        factory = self.session_factory()

        def create(coordinator):
            open_count = len(self.live_sessions())
            if open_count >= self.settings.max_sessions:
                raise ApiError(
                    429,
                    f"{open_count} sessions are open, the most this service allows",
                    "too_many_sessions",
                    {"Retry-After": "30"},
                )
            session = factory(
                coordinator, live.entry.graph, target_fps=target_fps, min_blend=min_blend
            )
            session.set_camera(camera)
            if live.denoise != "off":
                session.set_denoise(live.denoise)
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
        live.jpeg = None
        live.stop_encoder()
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
        live.deliver(frame, self.loop, self.settings.jpeg_quality, shows_update)
        live.frames += 1
        self._record_frame(getattr(live.session, "last_frame", None), "session")
        if self.metrics is not None and getattr(live.session, "last_frame", None) is None:
            self.metrics.frames.labels("session").inc()
            self.metrics.frame_seconds.labels("session").observe(t1 - t0)

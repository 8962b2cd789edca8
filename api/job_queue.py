"""The service's jobs: the queue in submission order, the one job running, each of its turns
on the render thread, and what they leave on disk, in the store and on the event streams.

The event loop calls :meth:`JobQueue.submit`, :meth:`cancel` and the readers; only the render
thread (``api.service``) calls :meth:`turn`, which starts the next job when none runs.
"""

import collections
import logging
import shutil
import traceback
from collections.abc import Callable

from api.events import EventHub
from api.job_run import JobRun, job_dir
from api.settings import Settings
from api.store import TERMINAL, Store
from tracer.errors import SceneError
from tracer.io.files import write_atomic
from tracer.io.images import write_image
from tracer.io.layers import write_layers
from tracer.scene.codec import decode_state, encode_state
from tracer.scene.model import SceneState

log = logging.getLogger("tilerender.api")


class JobQueue:
    """Queued jobs and the running one (see the module docstring)."""

    def __init__(
        self,
        settings: Settings,
        store: Store,
        events: EventHub,
        metrics=None,
        wake: Callable[[], None] = lambda: None,
    ) -> None:
        self.settings = settings
        self.store = store
        self.events = events
        self.metrics = metrics
        self._wake = wake
        self._queue: collections.deque[str] = collections.deque()
        self._cancelled: set[str] = set()
        self.run: JobRun | None = None

    # From any thread ---------------------------------------------------------------------------

    def submit(self, job_id: str) -> None:
        self._queue.append(job_id)
        self._wake()

    def cancel(self, job_id: str) -> None:
        self._cancelled.add(job_id)
        self._wake()

    def queue_length(self) -> int:
        return len(self._queue) + (1 if self.run is not None else 0)

    def progress(self, job_id: str) -> dict | None:
        """The running job's live progress; None for any other job."""
        run = self.run
        if run is not None and run.id == job_id:
            return run.progress()
        return None

    def queue_position(self, job_id: str) -> int | None:
        """Jobs that start before a queued job (0: it is next), None if it is not queued."""
        waiting = [j for j in list(self._queue) if j not in self._cancelled]
        return waiting.index(job_id) if job_id in waiting else None

    def save_state(self, job_id: str, state: SceneState) -> None:
        """The scene as the job will render it, beside its results (before it is queued)."""
        directory = job_dir(self.settings, job_id)
        directory.mkdir(parents=True, exist_ok=True)
        write_atomic(directory / "scene.tls", encode_state(state))

    def drop_state(self, job_id: str) -> None:
        """Remove what :meth:`save_state` wrote for a job that was not admitted."""
        shutil.rmtree(job_dir(self.settings, job_id), ignore_errors=True)

    def recover(self) -> None:
        """At start: queue unfinished jobs again (or fail them, with the reason)."""
        for record in self.store.unfinished_jobs():
            if not self.settings.resume_jobs:
                reason = "the service restarted while the job was unfinished (resume_jobs is off)"
                self.fail(record["id"], reason)
                continue
            snapshot = job_dir(self.settings, record["id"]) / "scene.tls"
            if not snapshot.is_file():
                self.fail(
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

    def fail(self, job_id: str, reason: str) -> None:
        if self.store.finish_job(job_id, "failed", reason):
            self._count("failed")
            self.events.publish(
                job_id, "error", {"job": job_id, "status": "failed", "message": reason}
            )

    # On the render thread ----------------------------------------------------------------------

    def current(self) -> JobRun | None:
        """The running job, after starting the next queued one if none runs."""
        if self.run is None:
            self._start_next()
        return self.run

    def fail_running(self, reason: str) -> None:
        if self.run is not None:
            run, self.run = self.run, None
            run.close()
            self.fail(run.id, reason)

    def turn(self, coordinator, turn_seconds: float, record_frame: Callable) -> None:
        """One turn of the running job (about ``turn_seconds`` of work); ``record_frame``
        sees the coordinator frame it rendered."""
        run = self.run
        if run.id in self._cancelled:
            self._drop(run)
            return
        run.sizer.seconds = turn_seconds
        try:
            result = run.step(coordinator)
        except Exception as exc:
            log.warning("job %s failed: %s", run.id, exc)
            log.debug("%s", traceback.format_exc())
            self.run = None
            message = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            self.fail(run.id, f"rendering failed: {message}")
            return
        record_frame(run.last_frame, "job")
        run.last_frame = None
        if run.id in self._cancelled:  # cancelled while this turn rendered: drop the frame
            self._drop(run)
            return
        if result is not None:
            self._keep_frame(run, *result)
        self.events.publish(run.id, "progress", {"job": run.id, **run.progress()})
        if run.finished:
            self._finish(run)

    def _start_next(self) -> None:
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
                self.fail(job_id, f"the job cannot start: {exc}")
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
                self._finish(run)
            return

    def _drop(self, run: JobRun) -> None:
        """Stop a cancelled job: no further turn renders any of it."""
        self._cancelled.discard(run.id)
        run.close()
        self.run = None

    def _keep_frame(self, run: JobRun, spec, layers: dict, info: dict) -> None:
        """A finished frame: on disk (its beauty as ``.npy``, or every layer as a ``.npz``
        bundle), in the store, then announced."""
        name = f"frame_{spec.number:06d}"
        if len(layers) == 1:
            path = job_dir(self.settings, run.id) / f"{name}.npy"
            write_image(path, layers["beauty"])
        else:
            path = job_dir(self.settings, run.id) / f"{name}.npz"
            kept = ("denoise", "ids", "error_of", "mean_spp", "adaptive_waves")
            write_layers(path, layers, {k: v for k, v in info.items() if k in kept})
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
                "error_of": info.get("error_of"),
                "mean_spp": info.get("mean_spp"),
                "url": f"/v1/jobs/{run.id}/frames/{spec.number}",
            },
        )

    def _finish(self, run: JobRun) -> None:
        self.run = None
        if self.store.finish_job(run.id, "done"):
            self._count("done")
            self.events.publish(
                run.id, "done", {"job": run.id, "status": "done", "frames": len(run.frames)}
            )

    def _count(self, status: str) -> None:
        if self.metrics is not None:
            self.metrics.jobs.labels(status).inc()

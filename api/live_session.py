"""An interactive session as the service holds it: the cluster's session, its latest JPEG
frame, the streams that watch it and its timings."""

import asyncio
import collections
import concurrent.futures
import io
import logging
import threading
import time

import numpy as np

from api.scenes import SceneEntry
from cluster.session import SessionFrame
from tracer.io.images import linear_to_srgb8
from tracer.scene import format as fmt

log = logging.getLogger("tilerender.api")

SESSION_RENDER_GRACE = 10.0
"""Seconds a session keeps rendering after its last request when no stream is open."""


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
        self.denoise = "off"
        """The quality the session's frames are denoised at (``off``: not denoised)."""
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
        self.denoise_ms: collections.deque = collections.deque(maxlen=64)
        self.frames_dropped = 0
        """Frames the encoder skipped because a newer one was waiting (denoising is slower
        than rendering)."""
        self.denoise_error: str | None = None
        """The denoiser's last error (its frames are then shown as they are)."""
        self._pending: tuple | None = None
        self._pending_lock = threading.Lock()
        self._encoder: concurrent.futures.ThreadPoolExecutor | None = None
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

    def deliver(
        self,
        frame: SessionFrame,
        loop: asyncio.AbstractEventLoop | None,
        jpeg_quality: int,
        shows_update: float | None,
    ) -> None:
        """Hand a cluster session's ``frame`` to this session's encoder thread (off the render
        thread), which denoises it if its session asks (``InteractiveSession.denoised``),
        encodes it and publishes it to the watchers on ``loop``, recording the times taken
        and, for a frame that shows a camera update, its latency. At most one frame waits: a
        newer one replaces it (keeping the earliest camera update's time), so a denoiser
        slower than the renderer drops frames rather than falling behind."""
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
        with self._pending_lock:
            waiting = self._pending
            if waiting is not None:
                self.frames_dropped += 1
                if waiting[2] is not None:
                    shows_update = waiting[2]
            self._pending = (frame, meta, shows_update)
            if self._encoder is None:
                self._encoder = concurrent.futures.ThreadPoolExecutor(
                    1, thread_name_prefix=f"tilerender-encode-{self.id}"
                )
            encoder = self._encoder
        if waiting is None:
            encoder.submit(self._encode_pending, loop, jpeg_quality)

    def stop_encoder(self) -> None:
        """Let the encoder thread go (the session closed): a frame still waiting is dropped."""
        with self._pending_lock:
            encoder, self._encoder, self._pending = self._encoder, None, None
        if encoder is not None:
            encoder.shutdown(wait=False, cancel_futures=True)

    def _encode_pending(self, loop: asyncio.AbstractEventLoop | None, jpeg_quality: int) -> None:
        """On the encoder: denoise, encode and publish the waiting frame (an error is logged:
        nothing else would see it on this thread)."""
        with self._pending_lock:
            pending, self._pending = self._pending, None
        if pending is None:
            return
        try:
            frame, meta, shows_update = pending
            image = frame.image
            meta["denoise"] = None
            if frame.denoise != "off":
                image, meta["denoise"] = self._denoised(frame)
            e0 = time.perf_counter()
            jpeg = encode_jpeg(image, jpeg_quality)
            self.encode_ms.append(round(1000 * (time.perf_counter() - e0), 3))
        except Exception:
            log.exception("session %s: a frame could not be encoded", self.id)
            return
        if loop is None or loop.is_closed():
            return

        def publish() -> None:
            self.publish(jpeg, meta)
            now = time.perf_counter()
            self.frame_times.append(now)
            if shows_update is not None:
                self.latencies.append(round(1000 * (now - shows_update), 3))

        loop.call_soon_threadsafe(publish)

    def _denoised(self, frame: SessionFrame) -> tuple[np.ndarray, dict]:
        """``(image, report)``: the frame denoised by its session, or, if the denoiser fails,
        the frame as it is and the error (logged when it first appears or changes)."""
        from tracer.post.denoise import DenoiseFailed, DenoiserUnavailable

        try:
            done = self.session.denoised(frame)
        except (DenoiserUnavailable, DenoiseFailed, ValueError) as exc:
            if self.denoise_error != str(exc):
                log.warning("session %s cannot denoise: %s", self.id, exc)
            self.denoise_error = str(exc)
            return frame.image, {"quality": frame.denoise, "error": str(exc)}
        self.denoise_error = None
        self.denoise_ms.append(round(1000 * done.seconds, 3))
        report = {
            "quality": done.quality,
            "guides": list(done.guides),
            "prefiltered": done.prefiltered,
            "seconds": round(done.seconds, 4),
        }
        return done.image, report

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
            "denoise_ms": mean(self.denoise_ms),
            "frames_dropped": self.frames_dropped,
            "denoise_error": self.denoise_error,
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


def set_camera_now(live: LiveSession, camera: fmt.Camera) -> None:
    """Thread-safe camera update (InteractiveSession.set_camera is thread-safe)."""
    live.camera_update_at = time.perf_counter()
    live.session.set_camera(camera)
    live.touch()

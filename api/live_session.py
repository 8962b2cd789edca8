"""An interactive session as the service holds it: the cluster's session, its latest JPEG
frame, the streams that watch it and its timings."""

import asyncio
import collections
import io
import time

import numpy as np

from api.scenes import SceneEntry
from tracer.io.images import linear_to_srgb8
from tracer.scene import format as fmt

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

    def deliver(self, frame, encoder, loop, quality: int, shows_update: float | None) -> None:
        """Encode a cluster session's ``frame`` on ``encoder`` (a thread pool, off the render
        thread) and publish it to the watchers on ``loop``, recording the encode time, the
        frame time and, for a frame that shows a camera update, its latency."""
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

        def encode() -> None:
            e0 = time.perf_counter()
            jpeg = encode_jpeg(image, quality)
            self.encode_ms.append(round(1000 * (time.perf_counter() - e0), 3))
            if loop is None or loop.is_closed():
                return

            def publish() -> None:
                self.publish(jpeg, meta)
                now = time.perf_counter()
                self.frame_times.append(now)
                if shows_update is not None:
                    self.latencies.append(round(1000 * (now - shows_update), 3))

            loop.call_soon_threadsafe(publish)

        encoder.submit(encode)

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


def set_camera_now(live: LiveSession, camera: fmt.Camera) -> None:
    """Thread-safe camera update (InteractiveSession.set_camera is thread-safe)."""
    live.camera_update_at = time.perf_counter()
    live.session.set_camera(camera)
    live.touch()

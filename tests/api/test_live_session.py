"""The service's hold on a session (``api.live_session.LiveSession``): frames are denoised,
encoded and published off the render thread, one at a time; a newer frame replaces one still
waiting (counted as dropped, its camera update's time kept); a failing denoiser shows the frame
as it is and says why, until it succeeds again."""

import asyncio
import threading
import time
from types import SimpleNamespace

import numpy as np

from api.live_session import LiveSession
from cluster.session import SessionFrame
from tracer.post.denoise import Denoised, DenoiseFailed


def frame(index: int, denoise: str = "fast") -> SessionFrame:
    image = np.full((6, 8, 3), 0.1 * index, np.float32)
    return SessionFrame(index, 0, image, 1, 8, 6, 1.0, 0.01, 1, denoise=denoise)


class SlowDenoiser:
    """A session whose denoiser takes ``seconds`` and fails while ``failing``."""

    def __init__(self, seconds: float) -> None:
        self.seconds = seconds
        self.failing = False
        self.calls: list[int] = []

    def denoised(self, shown: SessionFrame) -> Denoised:
        self.calls.append(shown.index)
        time.sleep(self.seconds)
        if self.failing:
            raise DenoiseFailed("OIDN says no")
        return Denoised(shown.image * 0.5, self.seconds, shown.denoise, (), False)


def running_loop():
    loop = asyncio.new_event_loop()
    thread = threading.Thread(target=loop.run_forever, daemon=True)
    thread.start()
    return loop, thread


def wait_for(condition, timeout: float = 10.0) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.01)


def test_a_frame_waiting_for_a_slow_denoiser_is_replaced_by_a_newer_one():
    loop, thread = running_loop()
    live = LiveSession("v1", SimpleNamespace(id="s1"), 8, 6, loop)
    live.session = SlowDenoiser(0.3)
    try:
        live.deliver(frame(1), loop, 85, None)
        wait_for(lambda: live.session.calls == [1])  # the first is being denoised
        update = time.perf_counter()
        live.deliver(frame(2), loop, 85, update)  # waits ...
        live.deliver(frame(3), loop, 85, None)  # ... and is replaced, its update's time kept
        wait_for(lambda: live.seq == 2)
        assert live.session.calls == [1, 3] and live.frames_dropped == 1
        assert live.meta["index"] == 3 and live.meta["denoise"]["quality"] == "fast"
        assert len(live.latencies) == 1 and live.latencies[0] >= 300  # from frame 2's update
        assert live.stats()["denoise_ms"] == 300.0

        live.session.failing = True
        live.deliver(frame(4), loop, 85, None)
        wait_for(lambda: live.seq == 3)
        assert live.meta["denoise"] == {"quality": "fast", "error": "OIDN says no"}
        assert live.stats()["denoise_error"] == "OIDN says no"
        live.session.failing = False
        live.deliver(frame(5, denoise="off"), loop, 85, None)  # shown as it is, no denoiser
        live.deliver(frame(6), loop, 85, None)
        wait_for(lambda: live.seq == 5 or (live.seq == 4 and live.frames_dropped == 2))
        wait_for(lambda: live.meta["index"] == 6)
        assert live.denoise_error is None and live.meta["denoise"]["quality"] == "fast"
    finally:
        live.stop_encoder()
        loop.call_soon_threadsafe(loop.stop)
        thread.join(5)

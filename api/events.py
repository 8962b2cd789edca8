"""Job events for Server-Sent Events: published from any thread, delivered on the event loop.

A subscriber is an ``asyncio.Queue`` on the loop; :meth:`EventHub.publish` hands each event
to every subscriber of its topic with ``loop.call_soon_threadsafe``, so the render thread never
blocks on a slow client. A queue that fills up (a client that stopped reading) drops its
oldest ``progress`` events first; ``frame``, ``done``, ``error`` and ``cancelled`` are kept.
"""

import asyncio
import json
import threading
import time

QUEUE_SIZE = 256
TERMINAL_EVENTS = ("done", "error", "cancelled")


class EventHub:
    def __init__(self) -> None:
        self._subscribers: dict[str, set[asyncio.Queue]] = {}
        self._lock = threading.Lock()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._ids = 0

    def bind(self, loop: asyncio.AbstractEventLoop) -> None:
        self._loop = loop

    def subscribe(self, topic: str) -> asyncio.Queue:
        queue: asyncio.Queue = asyncio.Queue(QUEUE_SIZE)
        with self._lock:
            self._subscribers.setdefault(topic, set()).add(queue)
        return queue

    def unsubscribe(self, topic: str, queue: asyncio.Queue) -> None:
        with self._lock:
            subs = self._subscribers.get(topic)
            if subs is not None:
                subs.discard(queue)
                if not subs:
                    del self._subscribers[topic]

    def publish(self, topic: str, kind: str, data: dict) -> None:
        with self._lock:
            queues = list(self._subscribers.get(topic, ()))
            self._ids += 1
            ident = self._ids
        loop = self._loop
        if not queues or loop is None or loop.is_closed():
            return
        event = {"id": ident, "event": kind, "data": {**data, "time": time.time()}}
        for queue in queues:
            try:
                loop.call_soon_threadsafe(_offer, queue, event)
            except RuntimeError:  # the loop closed meanwhile
                return


def _offer(queue: asyncio.Queue, event: dict) -> None:
    if queue.full():
        for _ in range(queue.qsize()):  # drop one progress event to make room
            old = queue.get_nowait()
            if old["event"] == "progress":
                break
            queue.put_nowait(old)
        else:
            return
    queue.put_nowait(event)


def sse(event: str, data: dict, ident: int | None = None) -> bytes:
    """One Server-Sent Event."""
    lines = []
    if ident is not None:
        lines.append(f"id: {ident}")
    lines.append(f"event: {event}")
    lines.append("data: " + json.dumps(data, separators=(",", ":")))
    return ("\n".join(lines) + "\n\n").encode()

"""Job events for Server-Sent Events: published from any thread, delivered on the event loop.

A subscriber is a :class:`Subscription` on the loop; :meth:`EventHub.publish` hands each event
to every subscriber of its topic with ``loop.call_soon_threadsafe``, so the render thread never
blocks on a slow client. A subscription keeps its events in the order they were published. One
that fills up (a client that stopped reading) drops its oldest ``progress`` event, or failing
that its oldest ``status`` or ``frame`` event; a terminal event (``done``, ``error``,
``cancelled``) is never dropped, so every stream can end.
"""

import asyncio
import json
import threading
import time
from collections import deque

QUEUE_SIZE = 256
TERMINAL_EVENTS = ("done", "error", "cancelled")
DROPPABLE = ("progress", "status", "frame")
"""What a full subscription gives up first: the oldest event of the first kind it holds."""


class Subscription:
    """One client's events, in publication order, at most ``size`` of them (see the module's
    docstring for what a full one drops). Used on the event loop only."""

    def __init__(self, size: int = QUEUE_SIZE) -> None:
        self.size = size
        self._events: deque[dict] = deque()
        self._ready = asyncio.Event()

    def offer(self, event: dict) -> None:
        if len(self._events) >= self.size:
            self._drop_oldest()
        self._events.append(event)
        self._ready.set()

    def _drop_oldest(self) -> None:
        for kind in DROPPABLE:
            for index, old in enumerate(self._events):
                if old["event"] == kind:
                    del self._events[index]
                    return

    async def get(self) -> dict:
        """The next event, waiting for one."""
        while not self._events:
            self._ready.clear()
            await self._ready.wait()
        return self._events.popleft()


class EventHub:
    def __init__(self) -> None:
        self._subscribers: dict[str, set[Subscription]] = {}
        self._lock = threading.Lock()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._ids = 0

    def bind(self, loop: asyncio.AbstractEventLoop) -> None:
        self._loop = loop

    def subscribe(self, topic: str) -> Subscription:
        queue = Subscription()
        with self._lock:
            self._subscribers.setdefault(topic, set()).add(queue)
        return queue

    def unsubscribe(self, topic: str, queue: Subscription) -> None:
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
                loop.call_soon_threadsafe(queue.offer, event)
            except RuntimeError:  # the loop closed meanwhile
                return


def sse(event: str, data: dict, ident: int | None = None) -> bytes:
    """One Server-Sent Event."""
    lines = []
    if ident is not None:
        lines.append(f"id: {ident}")
    lines.append(f"event: {event}")
    lines.append("data: " + json.dumps(data, separators=(",", ":")))
    return ("\n".join(lines) + "\n\n").encode()

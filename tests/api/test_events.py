"""Job events (``api.events``): a client that stops reading loses old progress, never the order
of what it is sent nor the terminal event that ends its stream."""

import asyncio
import threading

from api.events import QUEUE_SIZE, EventHub


def published(kinds: list[str]) -> list[dict]:
    """What one subscriber that read nothing until the end holds after ``kinds`` were published
    from another thread (as the render thread publishes), drained once publishing is over."""

    async def scenario() -> list[dict]:
        hub = EventHub()
        hub.bind(asyncio.get_running_loop())
        queue = hub.subscribe("job")

        def render_thread() -> None:
            for number, kind in enumerate(kinds):
                hub.publish("job", kind, {"n": number})

        thread = threading.Thread(target=render_thread)
        thread.start()
        await asyncio.to_thread(thread.join)
        await asyncio.sleep(0)  # let the loop run the offers scheduled last
        got = []
        while True:
            event = await asyncio.wait_for(queue.get(), 5)
            got.append(event)
            if event["event"] == "done":
                return got

    return asyncio.run(scenario())


def test_a_full_stream_still_ends_with_done():
    """More frame events than the queue holds, then done: the stream gets done (it used to
    be dropped, so such a stream never ended)."""
    got = published(["frame"] * (QUEUE_SIZE + 40) + ["done"])
    assert got[-1]["event"] == "done"
    assert len(got) == QUEUE_SIZE


def test_a_full_stream_keeps_publication_order_and_drops_progress_first():
    """Frames and progress interleaved past the queue's size: what arrives is in the order it
    was published, every frame event is kept while progress can be dropped, and done ends it."""
    kinds = ["frame" if k % 4 == 0 else "progress" for k in range(3 * QUEUE_SIZE)] + ["done"]
    got = published(kinds)
    numbers = [event["data"]["n"] for event in got]
    assert numbers == sorted(numbers), "events arrived out of order"
    frames = [k for k, kind in enumerate(kinds) if kind == "frame"]
    assert [e["data"]["n"] for e in got if e["event"] == "frame"] == frames
    assert got[-1]["event"] == "done" and len(got) == QUEUE_SIZE

"""Lossless test-state event channel (``WS /ws/events``).

Every event gets the next sequence number and is kept in a bounded history. A client receives every event in
order; a client that connects with ``?since=N`` first gets the history after N. Nothing is dropped silently:
a client whose backlog exceeds ``max_backlog`` is disconnected (close code 1013) and resynchronises by
reconnecting with ``since`` = the last sequence it saw (and ``GET /api/tests/{id}`` for the full record).
"""

from __future__ import annotations

import asyncio
import contextlib
import threading
import time
from collections import deque
from collections.abc import Awaitable, Callable
from typing import Any

from tcms_daq.service.clients import ClientQueue, WhenFull

CLOSE_TRY_AGAIN_LATER = 1013


async def run_until_either(sender: Awaitable[Any], closer: Awaitable[Any]) -> None:
    """Run a client's sender and its disconnect watcher until either ends; then cancel and await both."""
    tasks = [asyncio.ensure_future(sender), asyncio.ensure_future(closer)]
    try:
        await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
    finally:
        for task in tasks:
            task.cancel()
        for task in tasks:
            with contextlib.suppress(asyncio.CancelledError, Exception):  # the task's end is all we wait for
                await task


EventClient = ClientQueue[dict]


class EventHub:
    """Sequence-numbered JSON events; ``publish`` may be called from any thread."""

    def __init__(self, history: int = 2000, max_backlog: int = 5000):
        self.sequence = 0
        self.history: deque[dict] = deque(maxlen=history)
        self.max_backlog = max_backlog
        self.clients: set[EventClient] = set()
        self._lock = threading.Lock()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._listeners: list[Callable[[dict], None]] = []

    def add_listener(self, listener: Callable[[dict], None]) -> None:
        """Call ``listener(event)`` for every event, in order, from the publishing thread (it must return at once,
        e.g. hand the event to its own loop): the OPC UA bridge follows the test state this way."""
        with self._lock:
            self._listeners.append(listener)

    def bind_loop(self, loop: asyncio.AbstractEventLoop) -> None:
        self._loop = loop

    def publish(self, event_type: str, **fields: Any) -> dict:
        """Number, time-stamp, remember and deliver one event. Thread-safe; returns the event."""
        with self._lock:
            self.sequence += 1
            event = {"type": event_type, "seq": self.sequence, "time": time.time(), **fields}
            self.history.append(event)
            for listener in self._listeners:
                listener(event)
            loop = self._loop
            # deliver under the lock so events reach the loop in sequence order
            if loop is not None and not loop.is_closed():
                try:
                    loop.call_soon_threadsafe(self._deliver, event)
                except RuntimeError:  # loop closing during shutdown
                    pass
        return event

    def _deliver(self, event: dict) -> None:
        for client in tuple(self.clients):
            client.offer(event)

    def replay_after(self, since: int) -> list[dict]:
        with self._lock:
            return [e for e in self.history if e["seq"] > since]

    async def serve(
        self, send: Callable[[dict], Awaitable[None]], wait_closed: Awaitable[None], since: int | None = None
    ) -> EventClient:
        """Send the hello (and the replay after ``since``), then every new event until disconnect/overflow."""
        # lossless up to the backlog; beyond it the client is closed and resyncs with ?since=
        client: EventClient = ClientQueue(send, max_queue=self.max_backlog, when_full=WhenFull.CLOSE, name="events")
        # register before taking the replay so nothing falls between them; duplicates are filtered by seq
        self.clients.add(client)
        try:
            last = self.sequence
            await send({"type": "hello", "seq": last, "history_from": self.history[0]["seq"] if self.history else None})
            sent_upto = 0
            if since is not None:
                for event in self.replay_after(since):
                    await send(event)
                    sent_upto = event["seq"]
            await run_until_either(self._run_filtered(client, sent_upto), wait_closed)
        finally:
            self.clients.discard(client)
        return client

    async def _run_filtered(self, client: EventClient, sent_upto: int) -> None:
        """Send the client's events after the replay (registered before it, so duplicates are skipped)."""
        await client.run(lambda event: event if event["seq"] > sent_upto else None)

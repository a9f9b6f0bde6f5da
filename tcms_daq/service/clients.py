"""One outgoing queue per WebSocket client, for both hubs: the live frames and the events.

The producer ``offer``s without ever awaiting; a sender task (``run``) sends in order. What happens when the
queue is full is the one policy that differs:

* ``DROP_OLDEST`` (live frames): the oldest queued item is dropped and counted — a slow client sees fewer
  frames, never an older picture, and the others are not held back;
* ``CLOSE`` (events, which must not be lost silently): the client is marked ``overflowed`` and its sender
  stops; the endpoint closes the socket and the client resynchronises.

A send that blocks longer than ``stall_timeout_s`` evicts the client (``evicted``).
"""

from __future__ import annotations

import asyncio
import time
from collections import deque
from collections.abc import Awaitable, Callable
from enum import StrEnum
from typing import Generic, TypeVar

T = TypeVar("T")


class WhenFull(StrEnum):
    DROP_OLDEST = "drop_oldest"
    CLOSE = "close"


class ClientQueue(Generic[T]):
    """A bounded queue of items for one client and the task that sends them (see the module doc)."""

    def __init__(self, send: Callable[[T], Awaitable[None]], *, max_queue: int, when_full: WhenFull,
                 name: str = "client", stall_timeout_s: float | None = None):
        if max_queue < 1:
            raise ValueError(f"{name}: queue size must be >= 1")
        self.name = name
        self._send = send
        self._queue: deque[T] = deque()
        self._max_queue = max_queue
        self.when_full = when_full
        self.stall_timeout_s = stall_timeout_s
        self._ready = asyncio.Event()
        self.dropped = 0
        self.sent = 0
        self.evicted = False
        self.overflowed = False
        self.closed = False
        self.connected_at = time.monotonic()

    def offer(self, item: T) -> None:
        """Queue an item; never awaits (call it on the event loop)."""
        if self.closed:
            return
        if len(self._queue) >= self._max_queue:
            if self.when_full is WhenFull.CLOSE:
                self.overflowed = True
                self.close()
                return
            self._queue.popleft()
            self.dropped += 1
        self._queue.append(item)
        self._ready.set()

    @property
    def queued(self) -> int:
        return len(self._queue)

    async def run(self, prepare: Callable[[T], T | None] | None = None) -> None:
        """Send queued items until closed. ``prepare`` turns an item into what is sent (None: skip it)."""
        while not self.closed:
            if not self._queue:
                self._ready.clear()
                await self._ready.wait()
                continue
            item = self._queue.popleft()
            ready = item if prepare is None else prepare(item)
            if ready is None:
                continue
            try:
                if self.stall_timeout_s is None:
                    await self._send(ready)
                else:
                    await asyncio.wait_for(self._send(ready), self.stall_timeout_s)
            except TimeoutError:
                self.evicted = True
                self.closed = True
                return
            self.sent += 1

    def close(self) -> None:
        self.closed = True
        self._ready.set()

"""Publish/subscribe fan-out from the acquisition loop to its consumers.

The acquisition thread calls :meth:`FanOut.publish`, which never blocks: every subscriber has its own queue.

- **lossy** subscribers (live stream, UI) get a bounded queue; when it is full the oldest *data* message is
  dropped and counted (``dropped``). Event messages (state changes, interlock trips) are never dropped.
- **lossless** subscribers (recorders, stores) get an unbounded queue: nothing is ever dropped, the
  acquisition still never waits; ``max_backlog`` shows how far behind the consumer fell.

A subscriber is either pulled (``Subscription.get``) or a callable run on its own thread
(:meth:`FanOut.subscribe_callback`), so a slow or failing callback cannot stall acquisition.
"""

from __future__ import annotations

import threading
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from tcms_daq.samples import Samples


@dataclass(frozen=True)
class DataMessage:
    """One aligned, compensated batch: ``samples`` (time_s, torque_nm, angle_arcsec, extra encoder_arcsec)."""

    seq: int
    samples: Samples
    kind: str = "data"


@dataclass(frozen=True)
class EventMessage:
    """A state change or other event of a run: ``event`` name, ``time_s`` (acquisition clock), details."""

    seq: int
    event: str
    time_s: float
    details: dict[str, Any] = field(default_factory=dict)
    kind: str = "event"


Message = DataMessage | EventMessage


class Subscription:
    """One subscriber's queue. ``get`` blocks up to ``timeout`` s and returns None when nothing arrived."""

    def __init__(self, name: str, maxsize: int | None, fanout: FanOut):
        if maxsize is not None and maxsize < 1:
            raise ValueError(f"subscriber {name!r}: queue size must be >= 1")
        self.name = name
        self.maxsize = maxsize
        self.lossless = maxsize is None
        self.dropped = 0
        self.delivered = 0
        self.max_backlog = 0
        self._queue: deque[Message] = deque()
        self._cond = threading.Condition()
        self._closed = False
        self._fanout = fanout
        self.thread: threading.Thread | None = None  # the delivering thread of a callback subscriber

    def _put(self, message: Message) -> None:
        with self._cond:
            if self._closed:
                return
            if self.maxsize is not None and message.kind == "data":
                n_data = sum(1 for m in self._queue if m.kind == "data")
                if n_data >= self.maxsize:
                    for i, m in enumerate(self._queue):
                        if m.kind == "data":
                            del self._queue[i]
                            self.dropped += 1
                            break
            self._queue.append(message)
            self.max_backlog = max(self.max_backlog, len(self._queue))
            self._cond.notify()

    def get(self, timeout: float | None = None) -> Message | None:
        with self._cond:
            if not self._queue and not self._closed:
                self._cond.wait(timeout)
            if not self._queue:
                return None
            self.delivered += 1
            return self._queue.popleft()

    def drain(self) -> list[Message]:
        with self._cond:
            out = list(self._queue)
            self._queue.clear()
            self.delivered += len(out)
            return out

    @property
    def closed(self) -> bool:
        return self._closed

    def close(self, join_timeout_s: float = 2.0) -> None:
        """Stop receiving; a callback subscriber's thread first delivers what is queued (joined here)."""
        self._shut()
        self._join(join_timeout_s)

    def _shut(self) -> None:
        self._fanout.unsubscribe(self)
        with self._cond:
            self._closed = True
            self._cond.notify_all()

    def _join(self, timeout_s: float) -> None:
        if self.thread is not None and self.thread is not threading.current_thread():
            self.thread.join(timeout_s)


class FanOut:
    """Delivers every published message to every subscription without blocking the publisher."""

    def __init__(self) -> None:
        self._subs: list[Subscription] = []
        self._lock = threading.Lock()
        self._seq = 0
        self.callback_errors: list[str] = []
        self._sinks: list[Callable[[Samples], Any]] = []

    def subscribe(self, name: str, maxsize: int | None = 64) -> Subscription:
        """A pull subscription; ``maxsize=None`` makes it lossless (unbounded)."""
        sub = Subscription(name, maxsize, self)
        with self._lock:
            self._subs.append(sub)
        return sub

    def subscribe_callback(self, callback: Callable[[Message], Any], name: str | None = None,
                           maxsize: int | None = 64) -> Subscription:
        """Run ``callback(message)`` on a dedicated thread; exceptions are recorded, not raised."""
        sub = self.subscribe(name or str(getattr(callback, "__name__", "callback")), maxsize)

        def pump() -> None:
            while True:
                msg = sub.get(timeout=0.5)
                if msg is None:
                    if sub.closed:
                        return
                    continue
                try:
                    callback(msg)
                except Exception as exc:  # a consumer's bug must not stop acquisition
                    self.callback_errors.append(f"{sub.name}: {type(exc).__name__}: {exc}")

        thread = threading.Thread(target=pump, name=f"tcms-sub-{sub.name}", daemon=True)
        thread.start()
        sub.thread = thread
        return sub

    def add_sink(self, sink: Callable[[Samples], Any]) -> None:
        """Call ``sink(samples)`` with every data batch in the publisher's thread, without a queue: for a sink
        that copies the batch and returns (a run's sample buffer); it must never block."""
        with self._lock:
            self._sinks.append(sink)

    def remove_sink(self, sink: Callable[[Samples], Any]) -> None:
        with self._lock:
            if sink in self._sinks:
                self._sinks.remove(sink)

    def unsubscribe(self, sub: Subscription) -> None:
        with self._lock:
            if sub in self._subs:
                self._subs.remove(sub)

    def _next_seq(self) -> int:
        self._seq += 1
        return self._seq

    def publish_data(self, samples: Samples) -> DataMessage:
        with self._lock:
            msg = DataMessage(self._next_seq(), samples)
            subs = list(self._subs)
            sinks = list(self._sinks)
        for sink in sinks:
            try:
                sink(samples)
            except Exception as exc:  # recorded like a callback subscriber's failure; acquisition goes on
                self.callback_errors.append(f"sink {getattr(sink, '__qualname__', sink)}: {type(exc).__name__}: {exc}")
        for sub in subs:
            sub._put(msg)
        return msg

    def publish_event(self, event: str, time_s: float, **details: Any) -> EventMessage:
        with self._lock:
            msg = EventMessage(self._next_seq(), event, time_s, details)
            subs = list(self._subs)
        for sub in subs:
            sub._put(msg)
        return msg

    def close(self, join_timeout_s: float = 2.0) -> None:
        """Close every subscription; callback threads finish delivering what is queued, then stop."""
        with self._lock:
            subs = list(self._subs)
        for sub in subs:
            sub._shut()
        for sub in subs:  # all are closed first, so their threads drain side by side
            sub._join(join_timeout_s)

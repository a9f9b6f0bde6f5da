"""Testing aids for drivers: transcript testing of serial drivers (in the style of PyMeasure's
``expected_protocol``) and ``wait_until`` for tests against live simulators, ``ManualTime`` for a driver's own waiting without sleeps.

``ScriptedSerial`` stands in for a pyserial port: it holds a list of ``(expected_write, reply)`` pairs, checks
that the driver writes exactly the expected bytes in order, and then offers the scripted reply for reading
(``None`` = the instrument stays silent). Use it through a driver's ``opener`` argument::

    port = ScriptedSerial([(b"\\x02", b"+   12.34560 G  \\r\\n")])
    nd = driver_for(ND287, "socket://unused", opener=port.opener)
    ...
    port.assert_done()
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any, TypeVar

T = TypeVar("T")


def wait_until(predicate: Callable[[], bool], timeout_s: float = 2.0, poll_s: float = 0.01) -> bool:
    """Poll ``predicate`` until it is true (-> True) or ``timeout_s`` has passed (-> False)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(poll_s)
    return False


class ManualTime:
    """A :class:`drivers.timebase.Timebase` that moves only when told: ``sleep`` and ``advance`` add to
    ``now`` at once (no real waiting) and ``sleeps`` records each requested sleep in s."""

    def __init__(self, start_s: float = 1000.0):
        self._now_s = float(start_s)
        self.sleeps: list[float] = []

    def now(self) -> float:
        return self._now_s

    def sleep(self, duration_s: float) -> None:
        if duration_s > 0:
            self.sleeps.append(float(duration_s))
            self.advance(duration_s)

    def advance(self, duration_s: float) -> None:
        if duration_s > 0:
            self._now_s += float(duration_s)


class TranscriptMismatch(AssertionError):
    pass


class ScriptedSerial:
    def __init__(self, transcript: list[tuple[bytes, bytes | None]]):
        self.transcript = list(transcript)
        self.position = 0
        self.settings: dict[str, Any] = {}
        self.url: str | None = None
        self.is_open = False
        self._written = b""
        self._input = b""
        self.opened = 0

    def opener(self, url: str, **settings: Any) -> ScriptedSerial:
        self.url, self.settings = url, settings
        self.is_open = True
        self.opened += 1
        return self

    # -- the pyserial subset used by the drivers -------------------------------------------------------

    def write(self, data: bytes) -> int:
        if not self.is_open:
            raise TranscriptMismatch("write on a closed port")
        self._written += bytes(data)
        while self.position < len(self.transcript):
            expected, reply = self.transcript[self.position]
            if not self._written.startswith(expected[: len(self._written)]):
                raise TranscriptMismatch(
                    f"step {self.position}: wrote {self._written!r}, expected {expected!r}"
                )
            if len(self._written) < len(expected):
                break
            self._written = self._written[len(expected):]
            self.position += 1
            if reply is not None:
                self._input += reply
            if not self._written:
                break
        else:
            if self._written:
                raise TranscriptMismatch(f"unexpected write {self._written!r} after the end of the transcript")
        return len(data)

    def flush(self) -> None:
        pass

    def read(self, size: int = 1) -> bytes:
        data, self._input = self._input[:size], self._input[size:]
        return data

    def read_until(self, expected: bytes = b"\n", size: int | None = None) -> bytes:
        end = self._input.find(expected)
        n = len(self._input) if end < 0 else end + len(expected)
        if size is not None:
            n = min(n, size)
        return self.read(n)

    def reset_input_buffer(self) -> None:
        self._input = b""

    def close(self) -> None:
        self.is_open = False

    def assert_done(self) -> None:
        if self.position != len(self.transcript) or self._written:
            raise TranscriptMismatch(
                f"transcript stopped at step {self.position} of {len(self.transcript)}"
                + (f" with pending write {self._written!r}" if self._written else "")
            )


def driver_for(cls: type[T], url: str, **settings: object) -> T:
    """A driver built as a bench builds it, from its validated options model (``cls.options_model``): the
    ``settings`` that are options go into the model, the rest (``clock``, ``timebase``, a test's
    ``trace_packet`` …) to the constructor beside it. For tests and scripts that talk to one instrument."""
    model = cls.options_model  # type: ignore[attr-defined]
    options = model.model_validate({"url": url, **{k: v for k, v in settings.items() if k in model.model_fields}})
    build: Callable[..., T] = cls  # a driver class: (options, *, clock, timebase, …)
    return build(options, **{k: v for k, v in settings.items() if k not in model.model_fields})

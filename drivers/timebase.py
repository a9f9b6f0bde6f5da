"""The time a driver waits on: its own deadlines, retry delays and ages of received frames.

Two kinds of time meet in a driver. Readings are *stamped* with the bench's clock (``clock`` argument, see
:mod:`drivers.base`), so that every channel shares the bench's time base. The driver's *own* waiting — how old
the last heartbeat is, how long to poll for a state change, how long to keep the Modbus RTU line quiet, how
long to pause between reconnect attempts — runs on a :class:`Timebase`. On a bench that is real time
(:data:`REAL_TIME`); a test injects a manual timebase (``drivers.testing.ManualTime``) and lets time pass
without sleeping, so the outcome does not depend on how busy the machine is.

The transports' own socket and serial timeouts (pyserial, pymodbus, canopen's SDO client) stay in real time:
they bound a blocking read of the operating system.
"""

from __future__ import annotations

import time
from typing import Protocol


class Timebase(Protocol):
    def now(self) -> float:
        """Monotonic time in s."""
        ...

    def sleep(self, duration_s: float) -> None:
        """Let ``duration_s`` pass (nothing happens for ``duration_s`` ≤ 0)."""
        ...


class RealTime:
    """``time.monotonic`` and ``time.sleep``."""

    def now(self) -> float:
        return time.monotonic()

    def sleep(self, duration_s: float) -> None:
        if duration_s > 0:
            time.sleep(duration_s)


REAL_TIME = RealTime()

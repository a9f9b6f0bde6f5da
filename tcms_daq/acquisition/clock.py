"""Clocks for the acquisition loop and the procedure.

``MonotonicClock`` is real time (``time.monotonic``), used with real instruments and protocol simulators in
another process. ``SimulatedClock`` wraps a time source with ``now_s()`` and ``advance(duration_s)`` (the
virtual bench): its ``sleep`` advances the simulation, so an in-process test runs as fast as the physics can be
computed (``speed = inf``), or paced against real time for a live demo (``speed = 1`` is real time).

Both stamp in seconds. ``stepped`` tells the acquisition loop whether time moves only inside ``sleep`` (then
it reads the instruments synchronously after each step, which keeps in-process runs deterministic) or by itself
(then it reads in worker threads).
"""

from __future__ import annotations

import math
import time
from typing import Protocol, runtime_checkable


@runtime_checkable
class Clock(Protocol):
    stepped: bool

    def now(self) -> float:
        """Current time in s (monotonic)."""
        ...

    def sleep(self, duration_s: float) -> None:
        """Let ``duration_s`` of this clock's time pass."""
        ...

    def monotonic_at_zero_s(self) -> float | None:
        """``time.monotonic()`` at which this clock read 0 (``t_mono = this + now / speed``), None if unpaced."""
        ...


@runtime_checkable
class TimeSource(Protocol):
    def now_s(self) -> float: ...

    def advance(self, duration_s: float) -> None: ...


class MonotonicClock:
    """Real time (``time.monotonic``) × ``speed``; drivers of real instruments stamp with this clock's ``now``.

    ``speed`` > 1 only makes sense against protocol simulators whose physics also runs at that speed
    (``tcms sim serve --speed``): then ramps, dwells and timeouts are in the simulation's seconds.
    """

    stepped = False

    def __init__(self, speed: float = 1.0):
        if not (speed > 0 and math.isfinite(speed)):
            raise ValueError(f"real-time clock speed must be finite and > 0, got {speed}")
        self.speed = float(speed)

    def now(self) -> float:
        return time.monotonic() * self.speed

    def sleep(self, duration_s: float) -> None:
        if duration_s > 0:
            time.sleep(duration_s / self.speed)

    def monotonic_at_zero_s(self) -> float:
        """``time.monotonic()`` when this clock read 0 (``t_mono = this + now / speed``): 0."""
        return 0.0


class SimulatedClock:
    """Simulated time of a :class:`TimeSource`; ``sleep`` advances the simulation.

    speed: simulated seconds per real second; ``math.inf`` (default) never waits in real time.
    """

    stepped = True

    def __init__(self, source: TimeSource, speed: float = math.inf):
        if not speed > 0:
            raise ValueError(f"clock speed must be > 0, got {speed}")
        self.source = source
        self.speed = float(speed)
        self._real_start = time.monotonic()
        self._sim_start = source.now_s()

    def now(self) -> float:
        return self.source.now_s()

    def monotonic_at_zero_s(self) -> float | None:
        """``time.monotonic()`` at which this clock read 0 when paced (``t_mono = this + now / speed``);
        None when unpaced (``speed = inf``)."""
        if not math.isfinite(self.speed):
            return None
        return self._real_start - self._sim_start / self.speed

    def resync(self) -> None:
        """Pace from now on, dropping the real time that passed while nobody advanced this clock (a test's
        evaluation, the service's start-up) instead of running through it unpaced: otherwise the next sleeps
        return at once until the simulation has caught up, a burst of unpaced steps that takes the CPU from
        whatever runs beside them."""
        self._real_start = time.monotonic()
        self._sim_start = self.source.now_s()

    def sleep(self, duration_s: float) -> None:
        if duration_s <= 0:
            return
        if math.isfinite(self.speed):
            # pace against real time without accumulating drift
            target_real = self._real_start + (self.source.now_s() + duration_s - self._sim_start) / self.speed
            delay = target_real - time.monotonic()
            if delay > 0:
                time.sleep(delay)
        self.source.advance(duration_s)

"""One physics state and clock shared by every simulated instrument.

``SharedPhysics`` wraps a simulated bench (``sim.bench.SimulatedBench``: ``set_drive_enabled(bool)``,
``set_torque_target(target_nm, slope_nm_per_s)``, ``advance(duration_s) -> Samples``, ``now_s``) behind a lock,
remembers the latest sample for the instrument servers and calls tick hooks (the drive model's watchdogs and
quick-stop ramp) after every advance. ``start(speed)`` runs a ticker thread that advances the physics in real
time × speed; tests may instead call ``advance`` themselves.
"""

from __future__ import annotations

import collections
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

from tcms_daq.sim.instruments.loop import PeriodicThread

FILTER_WINDOW_S = 0.1  # an amplifier's filtered value averages this long (simulated s)
RECENT_SAMPLES = 2048  # torque readings kept for it
MAX_TICK_REAL_S = 0.1  # the longest real time one tick makes up


class BenchLike(Protocol):
    @property
    def now_s(self) -> float: ...

    def set_drive_enabled(self, enabled: bool) -> None: ...

    def set_torque_target(self, target_nm: float, slope_nm_per_s: float) -> None: ...

    def advance(self, duration_s: float) -> Any: ...


@dataclass(frozen=True)
class PhysicsReading:
    """The latest simulated sample: sensor torque (N·m), raw encoder angle (arcsec), applied (motor) torque,
    true output twist (arcsec), on the simulated clock (s)."""

    time_s: float = 0.0
    torque_nm: float = 0.0
    angle_arcsec: float = 0.0
    applied_torque_nm: float = 0.0
    true_angle_arcsec: float = 0.0


def _last(samples: Any, name: str, default: float) -> float:
    if name in ("time_s", "torque_nm", "angle_arcsec"):
        column = getattr(samples, name)
    else:
        column = getattr(samples, "extra", {}).get(name)
        if column is None:
            return default
    return float(column[-1]) if len(column) else default


TickHook = Callable[[PhysicsReading], None]


class SharedPhysics:
    """Thread-safe access to one simulated bench; the single clock of all simulated instruments."""

    def __init__(self, bench: BenchLike, *, tick_s: float = 0.002):
        self.bench = bench
        self.tick_s = float(tick_s)
        self._lock = threading.RLock()
        self._hooks: list[TickHook] = []
        self._latest = PhysicsReading(time_s=float(getattr(bench, "now_s", 0.0)))
        self._recent: collections.deque[tuple[float, float]] = collections.deque(maxlen=RECENT_SAMPLES)
        self._ticker = PeriodicThread(self._tick, self.tick_s, "sim-physics")
        self._last_tick_s = 0.0  # time.monotonic() of the previous real-time tick
        self.speed = 1.0
        self.advance(self.tick_s)  # a first sample so servers never serve an empty state

    @property
    def lock(self) -> threading.RLock:
        """The one lock of the shared state; instrument models use it too (a single lock order, no deadlock)."""
        return self._lock

    # -- physics access --------------------------------------------------------------------------------

    def latest(self) -> PhysicsReading:
        with self._lock:
            return self._latest

    def add_tick_hook(self, hook: TickHook) -> None:
        with self._lock:
            self._hooks.append(hook)

    def remove_tick_hook(self, hook: TickHook) -> None:
        with self._lock:
            if hook in self._hooks:
                self._hooks.remove(hook)

    def set_drive_enabled(self, enabled: bool) -> None:
        with self._lock:
            self.bench.set_drive_enabled(bool(enabled))

    def set_torque_target(self, target_nm: float, slope_nm_per_s: float) -> None:
        with self._lock:
            self.bench.set_torque_target(float(target_nm), float(slope_nm_per_s))

    def move_output(self, target_deg: float, velocity_deg_per_s: float) -> None:
        """Turn the output (the drive's profile position mode): ``SimulatedBench.move_output``."""
        with self._lock:
            self.bench.move_output(float(target_deg), float(velocity_deg_per_s))  # type: ignore[attr-defined]

    def stop_output(self) -> None:
        with self._lock:
            stop = getattr(self.bench, "stop_output", None)
            if stop is not None:
                stop()

    def output_moving(self) -> bool:
        with self._lock:
            return bool(getattr(self.bench, "output_moving", False))

    def now_s(self) -> float:
        """The simulated clock's present: the last tick's time and, while the ticker runs, the real time since it
        × speed (at most one tick's cap): what an instrument asked between two ticks reads at (a drivetrain's angles
        and torque are exact at any time of its present command)."""
        with self._lock:
            now = self._latest.time_s
            if self._ticker.running:
                now += min(max(0.0, time.monotonic() - self._last_tick_s), MAX_TICK_REAL_S) * self.speed
            return now

    def mean_torque_nm(self, window_s: float = FILTER_WINDOW_S) -> float:
        """The mean torque reading over the last ``window_s`` of simulated time (an amplifier's filtered value)."""
        with self._lock:
            if not self._recent:
                return self._latest.torque_nm
            end = self._recent[-1][0]
            values = [v for t, v in self._recent if t >= end - window_s]
            return sum(values) / len(values)

    def advance(self, duration_s: float) -> PhysicsReading:
        """Advance the physics by ``duration_s`` simulated seconds and run the tick hooks."""
        with self._lock:
            samples = self.bench.advance(duration_s)
            prev = self._latest
            if samples is not None and len(samples):
                for t, v in zip(samples.time_s[-RECENT_SAMPLES:].tolist(), samples.torque_nm[-RECENT_SAMPLES:].tolist(),
                                strict=True):
                    self._recent.append((t, v))
                applied = _last(samples, "applied_torque_nm", _last(samples, "torque_nm", 0.0))
                self._latest = PhysicsReading(
                    time_s=_last(samples, "time_s", prev.time_s),
                    torque_nm=_last(samples, "torque_nm", prev.torque_nm),
                    angle_arcsec=_last(samples, "angle_arcsec", prev.angle_arcsec),
                    applied_torque_nm=applied,
                    true_angle_arcsec=_last(samples, "true_angle_arcsec", _last(samples, "angle_arcsec", 0.0)),
                )
            reading = self._latest
            for hook in list(self._hooks):
                hook(reading)
            return reading

    # -- real-time ticker ------------------------------------------------------------------------------

    def start(self, speed: float = 1.0) -> None:
        """Advance the physics in a daemon thread at real time × ``speed``."""
        if speed <= 0:
            raise ValueError(f"speed must be > 0, got {speed}")
        if self._ticker.running:
            return
        self.speed = float(speed)
        self._last_tick_s = time.monotonic()
        self._ticker.start()

    def stop(self) -> None:
        self._ticker.stop()

    def _tick(self) -> None:
        now = time.monotonic()
        # cap one step so a stalled process does not produce a huge jump of the simulated clock (a jump shows its
        # clients the physics of a whole stall between two readings; the clock falls behind instead)
        self.advance(min(now - self._last_tick_s, MAX_TICK_REAL_S) * self.speed)
        self._last_tick_s = now

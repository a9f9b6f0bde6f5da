"""The acquisition loop: read instruments, align, compensate, publish, judge interlocks.

How time moves is the scheduler's business (:mod:`.schedulers`): **threaded** on real time (a reader thread per
instrument, a status poller, a coordinator running :meth:`AcquisitionLoop.step` every ``period_s``) or
**stepped** on the simulated clock (time advances only in :meth:`wait`, each advance followed by one synchronous
step: deterministic, as fast as the physics allows). The clock chooses (:mod:`tcms_daq.acquisition.clock`).

Each step drains the new readings, aligns torque onto the angle stamps (:mod:`.align`), applies the
compensator to the batch, publishes one :class:`~.fanout.DataMessage` (never blocking: see :mod:`.fanout`),
and has the interlock monitor (:mod:`.monitor`) judge it. The first trip is kept in :attr:`trip`; :meth:`wait` raises
:class:`InterlockTripped` so the procedure aborts.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from tcms_daq.acquisition.align import Aligner
from tcms_daq.acquisition.bench import POWERED_STATES, SECOND_AXIS_KINDS, Bench
from tcms_daq.acquisition.channel import Channel as _Channel
from tcms_daq.acquisition.channel import guarded_status
from tcms_daq.acquisition.fanout import FanOut
from tcms_daq.acquisition.interlocks import InterlockLimits, Trip, check_loader_status
from tcms_daq.acquisition.monitor import InterlockMonitor
from tcms_daq.acquisition.schedulers import SteppedScheduler, ThreadedScheduler
from tcms_daq.acquisition.station import StationMode
from tcms_daq.drivers.base import (
    INPUT_ANGLE_COLUMN,
    DeviceFault,
    Disconnected,
    InstrumentError,
    InstrumentTimeout,
    LoaderStatus,
)
from tcms_daq.errors import TcmsError
from tcms_daq.samples import Samples

log = logging.getLogger(__name__)
REAL_STEP_S = 0.02  # a paced simulated clock steps about 50 times per real second


def _error_trip(kind: str, exc: Exception, time_s: float) -> Trip | None:
    """The trip an instrument error means at once, whatever came before: the device reports its own fault,
    or its link is closed. None for errors that count (timeouts, garbled replies)."""
    if isinstance(exc, DeviceFault):
        return Trip("drive_fault" if kind in ("loader", "input_drive") else "device_fault",
                    f"{kind} instrument fault: {exc}", time_s)
    if isinstance(exc, Disconnected):
        return Trip("lost_instrument", f"lost {kind} instrument: {exc}", time_s)
    return None

class InterlockTripped(TcmsError):
    def __init__(self, trip: Trip):
        super().__init__(trip.reason)
        self.trip = trip


class AbortRequested(TcmsError):
    def __init__(self, reason: str = "aborted by operator"):
        super().__init__(reason)
        self.reason = reason


class AcquisitionLoop:
    """Reads a :class:`Bench` continuously and fans the compensated, aligned batches out.

    period_s: step period (clock time); on a paced simulated clock at least ``REAL_STEP_S`` of real time (the step
    grows with the speed: about 50 steps per real second whatever the speed, so the cost follows real time, and
    the interlocks judge each step's batch: their response is one step, ≤ 20 ms real = speed × 20 ms simulated,
    ``step_real_s`` / ``period_s``); read_interval_s: minimum time between two polls of one instrument in
    threaded mode (bounds the request rate of polled instruments); status_period_s: loader status poll period.
    """

    def __init__(self, bench: Bench, limits: InterlockLimits | None = None, *, period_s: float = 0.02,
                 read_interval_s: float = 0.002, status_period_s: float = 0.05, max_align_wait_s: float = 0.5):
        self.bench = bench
        self.clock = bench.clock
        self.monitor = InterlockMonitor(limits or InterlockLimits(bench_torque_limit_nm=bench.max_torque_nm),
                                        None if self.clock.stepped else getattr(self.clock, "speed", 1.0))
        speed = getattr(self.clock, "speed", math.inf)
        paced = self.clock.stepped and math.isfinite(speed)
        self.period_s = max(float(period_s), speed * REAL_STEP_S) if paced else float(period_s)
        self.condition_period_s = float(period_s)  # a wait for a condition checks it at the configured step
        # real seconds per step: the threaded scheduler's coordinator steps every period_s of real time
        self.step_real_s: float | None = (self.period_s / speed if paced else
                                          None if self.clock.stepped else self.period_s)
        self.read_interval_s = float(read_interval_s)
        self.status_period_s = float(status_period_s)
        self.fanout = FanOut()
        self.trip: Trip | None = None
        self.trip_event = threading.Event()
        self.loader_lock = threading.RLock()
        self._io_locks = {"angle": threading.RLock(), "torque": threading.RLock()}
        self.last_status: LoaderStatus | None = None
        # a drive in FAULT trips only while a run has the drive (armed after its fault reset and enable); between
        # runs the fault is shown (last_status) and the next run resets it
        self.drive_fault_armed = True
        # a run ended without confirming the loader disabled: the status poll disables it when it answers again
        self.disable_pending = False
        self._aligner = Aligner(max_wait_s=max_align_wait_s)
        self.max_align_wait_s = float(max_align_wait_s)
        now = self.clock.now()
        self._channels = {
            "angle": _Channel("angle", bench.angle.name, now),
            "torque": _Channel("torque", bench.torque.name, now),
            "loader": _Channel("loader", bench.loader.name, now),
        }
        # the second axis (when the bench has it): read all the time (a counter's FIFO must be drained), judged and
        # published only while a turning test has the bench (:class:`~.station.StationMode`)
        for kind in SECOND_AXIS_KINDS:
            drv = getattr(bench, kind)
            if drv is not None:
                self._channels[kind] = _Channel(kind, getattr(drv, "name", kind), now)
                if kind != "input_drive":
                    self._io_locks[kind] = threading.RLock()
        self.station = StationMode(self)
        self.scheduler: SteppedScheduler | ThreadedScheduler = (
            SteppedScheduler() if self.clock.stepped else ThreadedScheduler())
        self._step_lock = threading.Lock()
        self.running = False
        self.samples_published = 0

    # -- lifecycle ------------------------------------------------------------------------------------
    def start(self) -> AcquisitionLoop:
        if self.running:
            return self
        self.running = True
        now = self.clock.now()
        for ch in self._channels.values():
            ch.last_arrival_s = now
        self.scheduler.start(self)
        return self

    def stop(self) -> None:
        """Stop the worker threads, then publish what is still held (aligner flush)."""
        if not self.running:
            return
        self.scheduler.stop(self)
        self.step()
        if not self.station.flush():
            time_s, torque_nm, angle_arcsec = self._aligner.flush()
            if len(time_s):
                self._publish(time_s, torque_nm, angle_arcsec, self._aligner.released_extra)
        self.running = False

    def close(self) -> None:
        self.stop()
        self.fanout.close()

    def __enter__(self) -> AcquisitionLoop:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def limits(self) -> InterlockLimits:
        """The limits of the current run (judged by :attr:`monitor`)."""
        return self.monitor.limits

    def set_limits(self, limits: InterlockLimits) -> None:
        """New limits (a new run); clears a previous trip and re-arms the watchdog: every channel counts from
        now, so a reading that went stale while a trip was set does not end the next run at once."""
        self.monitor.rearm(limits)
        now = self.clock.now()
        for ch in self._channels.values():
            ch.last_arrival_s = now
            ch.errors_in_row = 0
        self.trip = None
        self.trip_event.clear()

    # -- reading --------------------------------------------------------------------------------------
    def _source(self, kind: str):
        return getattr(self.bench, kind)

    def read_once(self, kind: str) -> int:
        """One blocking read of the angle or torque source into its channel; returns the readings taken."""
        ch = self._channels[kind]
        try:
            with self._io_locks[kind]:
                ch.busy_since = self.clock.now()
                batch = self._source(kind).read()
        except InstrumentError as exc:
            self._on_error(ch, exc)
            return 0
        except Exception as exc:  # a driver bug is a lost instrument, not a crash of the loop
            self._on_error(ch, Disconnected(ch.name, f"{type(exc).__name__}: {exc}"))
            return 0
        finally:
            ch.busy_since = None
        ch.errors_in_row = 0
        if len(batch):
            with ch.lock:
                ch.pending.append(batch)
            ch.readings += len(batch)
            ch.last_arrival_s = self.clock.now()
            ch.last_arrival_real_s = time.monotonic()
            ch.last_value = float(batch.value[-1])
            inputs = (getattr(batch, "extra", None) or {}).get(INPUT_ANGLE_COLUMN)
            if inputs is not None and len(inputs):
                ch.last_input_arcsec = float(inputs[-1])
        return len(batch)

    def _on_error(self, ch: _Channel, exc: Exception) -> None:
        ch.errors_in_row += 1
        ch.errors_total += 1
        ch.last_error = str(exc)
        if not self.station.judged(ch):
            return
        now = self.clock.now()
        at_once = _error_trip(ch.kind, exc, now)
        if at_once is not None:
            self.raise_trip(at_once)
        elif ch.errors_in_row >= self.monitor.limits.max_consecutive_errors:
            what = "timeouts" if isinstance(exc, InstrumentTimeout) else "errors"
            self.raise_trip(Trip("lost_instrument", f"lost {ch.kind} instrument after {ch.errors_in_row} "
                                                    f"{what} in a row: {exc}", now))

    def poll_status(self, *, wait_for_lock: bool = True) -> LoaderStatus | None:
        """Read the loader's status (under the loader lock); None when it failed, or when the lock is held and
        ``wait_for_lock`` is False (a command is in progress: the poll is skipped, not queued)."""

        def read() -> LoaderStatus:
            status = self.bench.loader.status()
            return self._disable_left_enabled(status) if self.disable_pending else status

        status = guarded_status(self._channels["loader"], self.loader_lock, read, now=self.clock.now,
                                on_error=self._on_error, wait_for_lock=wait_for_lock)
        if status is None:
            return None
        self.last_status = status
        trip = check_loader_status(status) if self.drive_fault_armed else None
        if trip is not None:
            self.raise_trip(Trip(trip.interlock, trip.reason, self.clock.now()))
        return status

    def _disable_left_enabled(self, status: LoaderStatus) -> LoaderStatus:
        """A run ended without confirming the loader disabled (its link was down): now that the loader answers
        again, disable it if it is still powered, and read it again. Called under the loader lock."""
        if status.state in POWERED_STATES:
            self.bench.loader.disable()
            log.warning("%s answered again after a run that could not disable it (%s): disabled now",
                        self.bench.loader.name, status.state)
            status = self.bench.loader.status()
        self.disable_pending = False
        return status

    # -- one step ------------------------------------------------------------------------------------
    def step(self) -> None:
        """Drain new readings, align, compensate, publish, judge interlocks."""
        with self._step_lock:
            now = self.clock.now()
            self.scheduler.before_step(self, now)
            ang, extra = self._channels["angle"].take()
            tq, _ = self._channels["torque"].take()
            if not self.station.step(tq, now):  # a turning test's time base: the angle pairs
                t, torque, angle = self._aligner.push(ang.time_s, ang.value, tq.time_s, tq.value, now, extra)
                if len(t):
                    self._publish(t, torque, angle, self._aligner.released_extra)
            if self.running:
                self._check_stale(now)
        self._wake()

    def _publish(self, t: np.ndarray, torque: np.ndarray, raw_angle: np.ndarray,
                 extra: dict[str, np.ndarray] | None = None) -> None:
        angle = np.asarray(self.bench.compensate(raw_angle, torque, t), dtype=float)
        samples = Samples(t, torque, angle, {**(extra or {}), "encoder_arcsec": raw_angle})
        self.fanout.publish_data(samples)
        self.samples_published += len(t)
        trip = self.monitor.judge_batch(t, torque, angle)
        if trip is not None:
            self.raise_trip(trip)

    def _check_stale(self, now: float) -> None:
        trip = self.monitor.judge_freshness([c for c in self._channels.values() if self.station.judged(c)], now)
        if trip is not None:
            self.raise_trip(trip)

    def _root_cause(self, trip: Trip) -> Trip:
        """A torque/angle excursion is often the consequence of a drive fault (its fault reaction takes the
        torque off at once): ask the drive, and report its fault first when it has one."""
        if trip.interlock not in ("torque_rate", "torque_limit", "angle_window"):
            return trip
        try:
            with self.loader_lock:
                status = self.bench.loader.status()
        except Exception:
            return trip
        fault = check_loader_status(status)
        if fault is None:
            return trip
        return Trip(fault.interlock, f"{fault.reason}; {trip.reason}", trip.time_s)

    def raise_trip(self, trip: Trip) -> None:
        """Record the first trip (later ones are ignored) and publish it as an event."""
        if self.trip is not None:
            return
        trip = self._root_cause(trip)
        if self.trip is not None:
            return
        self.trip = trip
        self.trip_event.set()
        self.fanout.publish_event("interlock", trip.time_s, interlock=trip.interlock, reason=trip.reason)
        self._wake()

    def _wake(self) -> None:
        if isinstance(self.scheduler, ThreadedScheduler):
            self.scheduler.wake()

    # -- waiting (the procedure's only way to let time pass) ----------------------------------------
    def wait(self, duration_s: float, *, abort_event: threading.Event | None = None,
             until: Callable[[], bool] | None = None, check_trips: bool = True, step_s: float | None = None) -> bool:
        """Let ``duration_s`` of clock time pass while acquiring; returns early (True) when ``until()`` holds.

        A wait for a condition (``until``) steps at the configured period even on a fast paced clock, so a test
        does not hold at each setpoint for a long step. ``step_s`` (clock time) replaces the step period for this
        wait (the service's idle pump steps longer between tests). Raises InterlockTripped on a trip and
        AbortRequested when ``abort_event`` is set (unless ``check_trips`` is False: used while ramping down after a
        trip).
        """
        deadline = self.clock.now() + duration_s
        while True:
            if check_trips:
                if self.trip is not None:
                    raise InterlockTripped(self.trip)
                if abort_event is not None and abort_event.is_set():
                    raise AbortRequested(getattr(abort_event, "reason", "aborted by operator"))
            if until is not None and until():
                return True
            now = self.clock.now()
            if now >= deadline - 1e-9:
                return False
            step = step_s if step_s is not None else self.period_s if until is None else self.condition_period_s
            dt = min(step, deadline - now)
            self.scheduler.pass_time(self, now, dt)

    def channel_stats(self) -> dict[str, dict]:
        """Per channel: counters, the last value (the loader's is its status), how old it is in real seconds
        (``age_s``) and the link: ``up``, ``stale`` (no new reading for the watchdog time) or ``down`` (its last
        request failed: ``last_error`` says how). A reading of a link that is not up is not live."""
        now = time.monotonic()
        stale_s = self.stale_after_real_s()
        stats = {}
        for kind, c in self._channels.items():
            age_s = None if c.last_arrival_real_s is None else now - c.last_arrival_real_s
            link = ("down" if c.errors_in_row else
                    "stale" if age_s is None or age_s > stale_s else "up")
            stats[kind] = {"instrument": c.name, "readings": c.readings, "errors": c.errors_total,
                           "last_value": c.last_value if kind not in ("loader", "input_drive") else None,
                           "age_s": age_s, "link": link,
                           "last_error": c.last_error if c.errors_in_row else None}
        return stats

    def stale_after_real_s(self) -> float:
        """Real seconds without a reading after which a channel counts as stale (the watchdog time; 1 s at least)."""
        timeout = self.monitor.stale_timeout_s()
        speed = getattr(self.clock, "speed", 1.0)
        real = timeout / speed if timeout is not None and math.isfinite(speed) and speed > 0 else None
        return max(1.0, real or 1.0)

    def latest_torque_nm(self) -> float | None:
        return self._channels["torque"].last_value

    def instrument_command(self, kind: str, fn: Callable[..., Any], *args: Any) -> Any:
        """Call a method of the angle/torque source between two reads (e.g. ``tare``); a failure trips as
        :meth:`loader_command`'s do, naming the instrument, and is re-raised."""
        try:
            with self._io_locks[kind]:
                return fn(*args)
        except InstrumentError as exc:
            self.raise_trip(self._command_trip(kind, exc))
            raise

    def loader_command(self, fn: Callable[..., Any], *args: Any) -> Any:
        """Call a loader method under the loader lock (the status poller uses the same driver); its failures
        count for the lost-instrument interlock like failed status polls, trip naming the loader (a command
        that did not go through leaves the run without its setpoint), and are re-raised."""
        ch = self._channels["loader"]
        with self.loader_lock:
            ch.busy_since = self.clock.now()
            try:
                return fn(*args)
            except InstrumentError as exc:
                self._on_error(ch, exc)
                self.raise_trip(self._command_trip("loader", exc))
                raise
            finally:
                ch.busy_since = None

    def trip_not_followed(self, what: str) -> InterlockTripped:
        """Trip the run because the loader did not do what it was told (``what``: setpoint and measurement) and
        return the exception to raise. A channel that shows why is named as the cause, the torque measurement
        first (a stale reading is not the drive's fault), then the loader's link (a mute drive takes setpoints
        it does not follow): either would otherwise end the run before the watchdog calls it lost."""
        now = self.clock.now()
        for kind in ("torque", "loader"):
            problem = self.monitor.link_problem(self._channels[kind], now)
            if problem is not None:
                trip = Trip("lost_instrument", f"lost {kind} instrument: {what}; {problem}", now)
                break
        else:
            trip = Trip("setpoint_not_followed", f"loader did not follow its setpoint: {what}", now)
        self.raise_trip(trip)
        return InterlockTripped(self.trip or trip)

    def _command_trip(self, kind: str, exc: InstrumentError) -> Trip:
        """The trip of a failed command to the ``kind`` instrument (a no-op in :meth:`raise_trip` when
        :meth:`_on_error` already tripped for it): a command without an answer is a lost instrument."""
        now = self.clock.now()
        trip = _error_trip(kind, exc, now)
        if trip is not None:
            return trip
        if isinstance(exc, InstrumentTimeout):
            return Trip("lost_instrument", f"lost {kind} instrument: {exc}", now)
        return Trip("command_failed", f"{kind} command failed: {exc}", now)

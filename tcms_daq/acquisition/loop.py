"""The acquisition loop: read instruments, align, compensate, publish, judge interlocks.

Two ways time can move (see :mod:`tcms_daq.acquisition.clock`):

- **threaded** (real time; real instruments or protocol simulators in another process): one worker thread per
  instrument calls its blocking ``read()`` (the driver stamps each reading), a status poller watches the
  loader, and a coordinator thread runs :meth:`AcquisitionLoop.step` every ``period_s``.
- **stepped** (simulated clock of the in-process virtual bench): time advances only in :meth:`wait`, which
  advances the clock by ``period_s`` and runs :meth:`step` synchronously after each advance. The run is
  deterministic and as fast as the physics allows.

Each step drains the new readings, aligns torque onto the angle stamps (:mod:`.align`), applies the
compensator to the batch, publishes one :class:`~.fanout.DataMessage` (never blocking: see :mod:`.fanout`),
and has the interlock monitor (:mod:`.monitor`) judge it. The first trip is kept in :attr:`trip`; :meth:`wait` raises
:class:`InterlockTripped` so the procedure aborts.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from drivers.base import (
    Batch,
    DeviceFault,
    Disconnected,
    InstrumentError,
    InstrumentTimeout,
    LoaderStatus,
    concat_common_columns,
)
from tcms_daq.acquisition.align import Aligner
from tcms_daq.acquisition.bench import Bench
from tcms_daq.acquisition.fanout import FanOut
from tcms_daq.acquisition.interlocks import InterlockLimits, Trip, check_loader_status
from tcms_daq.acquisition.monitor import InterlockMonitor
from tcms_daq.errors import TcmsError
from tcms_daq.samples import Samples

log = logging.getLogger(__name__)
# CiA 402 states in which the drive can apply torque (a loader left in one after a run is disabled)
POWERED_STATES = frozenset({"OPERATION ENABLED", "SWITCHED ON", "QUICK STOP ACTIVE"})
WORKER_RESTART_S = 0.5  # pause before a failed acquisition worker starts again (real time)


class InterlockTripped(TcmsError):
    def __init__(self, trip: Trip):
        super().__init__(trip.reason)
        self.trip = trip


class AbortRequested(TcmsError):
    def __init__(self, reason: str = "aborted by operator"):
        super().__init__(reason)
        self.reason = reason


class _Channel:
    """Book-keeping for one instrument: pending batches, errors in a row, last arrival (clock time)."""

    def __init__(self, kind: str, name: str, now_s: float):
        self.kind = kind
        self.name = name
        self.pending: list[Batch] = []
        self.lock = threading.Lock()
        self.errors_in_row = 0
        self.errors_total = 0
        self.readings = 0
        self.last_arrival_s = now_s
        self.last_value: float | None = None
        self.last_error: str | None = None
        self.busy_since: float | None = None  # clock time the pending request started

    def take(self) -> tuple[Batch, dict[str, np.ndarray]]:
        """The pending readings as one batch, and the extra columns all of them carry."""
        with self.lock:
            parts, self.pending = self.pending, []
        if not parts:
            return Batch.empty(), {}
        extra = concat_common_columns([getattr(p, "extra", None) or {} for p in parts])
        if len(parts) == 1:
            return parts[0], extra
        return Batch(np.concatenate([p.time_s for p in parts]), np.concatenate([p.value for p in parts])), extra


class AcquisitionLoop:
    """Reads a :class:`Bench` continuously and fans the compensated, aligned batches out.

    period_s: step period (clock time); read_interval_s: minimum time between two polls of one instrument in
    threaded mode (bounds the request rate of polled instruments); status_period_s: loader status poll period.
    """

    def __init__(self, bench: Bench, limits: InterlockLimits | None = None, *, period_s: float = 0.02,
                 read_interval_s: float = 0.002, status_period_s: float = 0.05, max_align_wait_s: float = 0.5):
        self.bench = bench
        self.clock = bench.clock
        self.monitor = InterlockMonitor(limits or InterlockLimits(bench_torque_limit_nm=bench.max_torque_nm),
                                        None if self.clock.stepped else getattr(self.clock, "speed", 1.0))
        self.period_s = float(period_s)
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
        now = self.clock.now()
        self._channels = {
            "angle": _Channel("angle", bench.angle.name, now),
            "torque": _Channel("torque", bench.torque.name, now),
            "loader": _Channel("loader", bench.loader.name, now),
        }
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._tick = threading.Condition()
        self._step_lock = threading.Lock()
        self._last_status_poll = -np.inf
        self.running = False
        self.samples_published = 0

    # -- lifecycle ------------------------------------------------------------------------------------
    def start(self) -> AcquisitionLoop:
        if self.running:
            return self
        self.running = True
        self._stop.clear()
        now = self.clock.now()
        for ch in self._channels.values():
            ch.last_arrival_s = now
        if not self.clock.stepped:
            for kind in ("angle", "torque"):
                self._spawn(self._reader, kind)
            self._spawn(self._status_poller)
            self._spawn(self._coordinator)
        return self

    def _spawn(self, target: Callable, *args: Any) -> None:
        name = f"tcms-acq-{target.__name__}-{args}"

        def guarded() -> None:
            """A worker that fails on a bug ends the run with the reason (a trip), is logged with its traceback
            and starts again, so monitoring goes on for the next test; it never dies silently."""
            while not self._stop.is_set():
                try:
                    target(*args)
                    return
                except Exception as exc:
                    log.exception("%s failed; restarting it in %g s", name, WORKER_RESTART_S)
                    self.raise_trip(Trip("internal_error", f"acquisition thread {target.__name__.strip('_')} "
                                         f"failed: {type(exc).__name__}: {exc}", self.clock.now()))
                    if self._stop.wait(WORKER_RESTART_S):
                        return

        t = threading.Thread(target=guarded, name=name, daemon=True)
        t.start()
        self._threads.append(t)

    def stop(self) -> None:
        """Stop the worker threads, then publish what is still held (aligner flush)."""
        if not self.running:
            return
        self._stop.set()
        for t in self._threads:
            t.join(timeout=5.0)
        self._threads.clear()
        self.step()
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
        return self.bench.angle if kind == "angle" else self.bench.torque

    def _read_once(self, kind: str) -> int:
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
            ch.last_value = float(batch.value[-1])
        return len(batch)

    def _on_error(self, ch: _Channel, exc: Exception) -> None:
        ch.errors_in_row += 1
        ch.errors_total += 1
        ch.last_error = str(exc)
        now = self.clock.now()
        if isinstance(exc, DeviceFault):
            interlock = "drive_fault" if ch.kind == "loader" else "device_fault"
            self.raise_trip(Trip(interlock, f"{ch.kind} instrument fault: {exc}", now))
        elif isinstance(exc, Disconnected):
            self.raise_trip(Trip("lost_instrument", f"lost {ch.kind} instrument: {exc}", now))
        elif ch.errors_in_row >= self.monitor.limits.max_consecutive_errors:
            what = "timeouts" if isinstance(exc, InstrumentTimeout) else "errors"
            self.raise_trip(Trip("lost_instrument", f"lost {ch.kind} instrument after {ch.errors_in_row} "
                                                    f"{what} in a row: {exc}", now))

    def _reader(self, kind: str) -> None:
        while not self._stop.is_set():
            started = time.monotonic()
            n = self._read_once(kind)
            rest = self.read_interval_s - (time.monotonic() - started)
            if n == 0:
                rest = max(rest, self.read_interval_s)
            if rest > 0:
                self._stop.wait(rest)

    def poll_status(self, *, wait_for_lock: bool = True) -> LoaderStatus | None:
        """Read the loader's status (under the loader lock); None when it failed, or when the lock is held and
        ``wait_for_lock`` is False (a command is in progress: the poll is skipped, not queued)."""
        ch = self._channels["loader"]
        if not self.loader_lock.acquire(blocking=wait_for_lock):
            return None
        ch.busy_since = self.clock.now()  # waiting for the lock counts: the loader is busy with a command
        try:
            status = self.bench.loader.status()
            if self.disable_pending:
                status = self._disable_left_enabled(status)
        except InstrumentError as exc:
            self._on_error(ch, exc)
            return None
        except Exception as exc:
            self._on_error(ch, Disconnected(ch.name, f"{type(exc).__name__}: {exc}"))
            return None
        finally:
            ch.busy_since = None
            self.loader_lock.release()
        ch.errors_in_row = 0
        ch.readings += 1
        ch.last_arrival_s = self.clock.now()
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

    def _status_poller(self) -> None:
        # Monitoring never stops, a trip or not (the bench view shows the drive's real state, and the next run
        # starts from a fresh reading); while the procedure commands the loader (ramp down, disable, reconnect
        # attempts) the poll is skipped rather than competing for the driver.
        while not self._stop.wait(self.status_period_s):
            self.poll_status(wait_for_lock=False)

    def _coordinator(self) -> None:
        while not self._stop.wait(self.period_s):
            self.step()

    # -- one step ------------------------------------------------------------------------------------
    def step(self) -> None:
        """Drain new readings, align, compensate, publish, judge interlocks."""
        with self._step_lock:
            now = self.clock.now()
            if self.clock.stepped:
                self._read_once("angle")
                self._read_once("torque")
                if now - self._last_status_poll >= self.status_period_s - 1e-12:
                    self._last_status_poll = now
                    self.poll_status()
            ang, extra = self._channels["angle"].take()
            tq, _ = self._channels["torque"].take()
            t, torque, angle = self._aligner.push(ang.time_s, ang.value, tq.time_s, tq.value, now, extra)
            if len(t):
                self._publish(t, torque, angle, self._aligner.released_extra)
            if self.running:
                self._check_stale(now)
        with self._tick:
            self._tick.notify_all()

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
        trip = self.monitor.judge_freshness(self._channels.values(), now)
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
        with self._tick:
            self._tick.notify_all()

    # -- waiting (the procedure's only way to let time pass) ----------------------------------------
    def wait(self, duration_s: float, *, abort_event: threading.Event | None = None,
             until: Callable[[], bool] | None = None, check_trips: bool = True) -> bool:
        """Let ``duration_s`` of clock time pass while acquiring; returns early (True) when ``until()`` holds.

        Raises InterlockTripped on a trip and AbortRequested when ``abort_event`` is set (unless
        ``check_trips`` is False: used while ramping down after a trip).
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
            dt = min(self.period_s, deadline - now)
            if self.clock.stepped:
                self.clock.sleep(dt)
                if self.clock.now() <= now:  # a clock that cannot move would spin here for ever
                    raise TcmsError(f"the simulated clock did not advance from {now!r} s by {dt!r} s")
                self.step()
            else:
                with self._tick:
                    self._tick.wait(dt)

    def channel_stats(self) -> dict[str, dict]:
        return {k: {"instrument": c.name, "readings": c.readings, "errors": c.errors_total}
                for k, c in self._channels.items()}

    def latest_torque_nm(self) -> float | None:
        return self._channels["torque"].last_value

    def instrument_command(self, kind: str, fn: Callable[..., Any], *args: Any) -> Any:
        """Call a method of the angle/torque source between two reads (e.g. ``tare``)."""
        with self._io_locks[kind]:
            return fn(*args)

    def loader_command(self, fn: Callable[..., Any], *args: Any) -> Any:
        """Call a loader method under the loader lock (the status poller uses the same driver); its failures
        count for the lost-instrument interlock like failed status polls, and are re-raised."""
        ch = self._channels["loader"]
        with self.loader_lock:
            ch.busy_since = self.clock.now()
            try:
                return fn(*args)
            except InstrumentError as exc:
                self._on_error(ch, exc)
                raise
            finally:
                ch.busy_since = None

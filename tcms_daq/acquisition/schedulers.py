"""How time moves for the acquisition loop: two strategies behind one small interface.

- :class:`SteppedScheduler` (the simulated clock of the in-process bench): nothing runs in the background;
  time advances only when the procedure lets it pass (``pass_time``), and each advance is followed by one
  synchronous step that first reads every instrument (and the loader's status at its period). Deterministic,
  as fast as the physics allows.
- :class:`ThreadedScheduler` (real time: real instruments, or protocol simulators in another process): one
  reader thread per instrument calls its blocking ``read()``, a status poller watches the loader and a
  coordinator steps every ``period_s``; ``pass_time`` waits for the next step. A worker that fails on a bug
  trips ``internal_error`` with the reason, is logged and starts again: it never dies silently.

The loop (:class:`~.loop.AcquisitionLoop`) owns the channels, the step and the interlocks; a scheduler only
decides who calls what, and when.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Protocol

from tcms_daq.acquisition.interlocks import Trip
from tcms_daq.errors import TcmsError

if TYPE_CHECKING:
    from tcms_daq.acquisition.loop import AcquisitionLoop

log = logging.getLogger(__name__)
WORKER_RESTART_S = 0.5  # pause before a failed acquisition worker starts again (real time)


class Scheduler(Protocol):
    def start(self, loop: AcquisitionLoop) -> None: ...

    def stop(self, loop: AcquisitionLoop) -> None: ...

    def before_step(self, loop: AcquisitionLoop, now_s: float) -> None:
        """Called at the start of each step, under the step lock."""
        ...

    def pass_time(self, loop: AcquisitionLoop, now_s: float, dt_s: float) -> None:
        """Let ``dt_s`` of clock time pass (from ``now_s``) while acquiring."""
        ...


class SteppedScheduler:
    def __init__(self) -> None:
        self._last_status_poll_s = float("-inf")

    def start(self, loop: AcquisitionLoop) -> None:
        pass

    def stop(self, loop: AcquisitionLoop) -> None:
        pass

    def before_step(self, loop: AcquisitionLoop, now_s: float) -> None:
        loop.read_once("angle")
        loop.read_once("torque")
        for kind in loop.station.kinds:
            loop.read_once(kind)
        if now_s - self._last_status_poll_s >= loop.status_period_s - 1e-12:
            self._last_status_poll_s = now_s
            loop.poll_status()
            loop.station.poll_drive()

    def pass_time(self, loop: AcquisitionLoop, now_s: float, dt_s: float) -> None:
        loop.clock.sleep(dt_s)
        if loop.clock.now() <= now_s:  # a clock that cannot move would spin here for ever
            raise TcmsError(f"the simulated clock did not advance from {float(now_s):.9g} s by {float(dt_s):.9g} s")
        loop.step()


class ThreadedScheduler:
    def __init__(self) -> None:
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._tick = threading.Condition()

    def start(self, loop: AcquisitionLoop) -> None:
        self._stop.clear()
        for kind in ("angle", "torque", *loop.station.kinds):
            self._spawn(loop, self._reader, kind)
        self._spawn(loop, self._status_poller)
        if loop.bench.input_drive is not None:
            self._spawn(loop, self._input_drive_poller)
        self._spawn(loop, self._coordinator)

    def stop(self, loop: AcquisitionLoop) -> None:
        self._stop.set()
        for t in self._threads:
            t.join(timeout=5.0)
        self._threads.clear()

    def before_step(self, loop: AcquisitionLoop, now_s: float) -> None:
        pass

    def pass_time(self, loop: AcquisitionLoop, now_s: float, dt_s: float) -> None:
        with self._tick:
            self._tick.wait(dt_s)

    def wake(self) -> None:
        """Wake whoever waits in ``pass_time`` (after a step, or a trip)."""
        with self._tick:
            self._tick.notify_all()

    # -- the workers -------------------------------------------------------------------------------------
    def _spawn(self, loop: AcquisitionLoop, target: Callable[..., None], *args: Any) -> None:
        name = f"tcms-acq-{target.__name__.strip('_')}-{'-'.join(map(str, args))}".rstrip("-")

        def guarded() -> None:
            while not self._stop.is_set():
                try:
                    target(loop, *args)
                    return
                except Exception as exc:
                    log.exception("%s failed; restarting it in %g s", name, WORKER_RESTART_S)
                    loop.raise_trip(Trip("internal_error", f"acquisition thread {target.__name__.strip('_')} "
                                         f"failed: {type(exc).__name__}: {exc}", loop.clock.now()))
                    if self._stop.wait(WORKER_RESTART_S):
                        return

        thread = threading.Thread(target=guarded, name=name, daemon=True)
        thread.start()
        self._threads.append(thread)

    def _reader(self, loop: AcquisitionLoop, kind: str) -> None:
        while not self._stop.is_set():
            started = time.monotonic()
            n = loop.read_once(kind)
            rest = loop.read_interval_s - (time.monotonic() - started)
            if n == 0:
                rest = max(rest, loop.read_interval_s)
            if rest > 0:
                self._stop.wait(rest)

    def _status_poller(self, loop: AcquisitionLoop) -> None:
        # Monitoring never stops, a trip or not (the bench view shows the drive's real state, and the next run
        # starts from a fresh reading); while the procedure commands the loader (ramp down, disable, reconnect
        # attempts) the poll is skipped rather than competing for the driver.
        while not self._stop.wait(loop.status_period_s):
            loop.poll_status(wait_for_lock=False)

    def _input_drive_poller(self, loop: AcquisitionLoop) -> None:
        while not self._stop.wait(loop.status_period_s):
            loop.station.poll_drive(wait_for_lock=False)

    def _coordinator(self, loop: AcquisitionLoop) -> None:
        while not self._stop.wait(loop.period_s):
            loop.step()

"""The acquisition's second axis: the input drive, the input torque and the angle pair source (issue 28).

A bench with its second axis reads the pair source and the input torque all the time (a counter card's FIFO must be
drained) and polls the input drive's status, as it does the loader's; outside a turning test their readings are
dropped and their errors and staleness counted, not tripped on (a stiffness test does not need them). While a
turning test has the bench (:meth:`StationMode.set_active`):

- the angle pairs are the time base of what is published (:class:`~.align.StationAligner`): the loader's torque
  (``torque_nm``) and the input torque (``input_torque_nm``) interpolated onto them, the output angle compensated
  (``angle_arcsec``; raw: ``encoder_arcsec``), the input angle beside it (``input_angle_arcsec``); the angle channel
  is read and its readings dropped;
- the second axis's channels are judged like the loader's: the watchdog, failed requests (``lost_instrument``), the
  input drive's faults once the procedure has armed it (``drive_fault`` naming the input drive).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np

from tcms_daq.acquisition.align import Aligner, StationAligner
from tcms_daq.acquisition.interlocks import Trip
from tcms_daq.drivers.base import INPUT_ANGLE_COLUMN, Batch, Disconnected, InputDriveStatus, InstrumentError
from tcms_daq.errors import TcmsError

if TYPE_CHECKING:
    from tcms_daq.acquisition.loop import AcquisitionLoop

SECOND_AXIS = ("input_drive", "input_torque", "input_angle")


class StationMode:
    """The second axis of one :class:`~.loop.AcquisitionLoop` (module docstring)."""

    def __init__(self, loop: AcquisitionLoop):
        self.loop = loop
        self.active = False
        self.armed = False  # a fault of the input drive trips while a turning test has it (after its reset)
        self.drive_lock = threading.RLock()
        self.last_status: InputDriveStatus | None = None
        self._aligner: StationAligner | None = None

    @property
    def kinds(self) -> tuple[str, ...]:
        """The second axis's sensor channels this bench has (read like the angle and the torque)."""
        return tuple(k for k in ("input_angle", "input_torque") if k in self.loop._channels)

    def set_active(self, active: bool) -> None:
        """A turning test takes the bench (True) or leaves it (False); what came before is not the test's."""
        loop = self.loop
        with loop._step_lock:
            if active and "input_angle" not in loop._channels:
                raise TcmsError("the bench has no angle pair source ([instruments.input_angle])")
            self.active = bool(active)
            if active:
                sides = ("torque_nm", "input_torque_nm") if "input_torque" in loop._channels else ("torque_nm",)
                self._aligner = StationAligner(sides, loop.max_align_wait_s)
                now = loop.clock.now()
                for kind in SECOND_AXIS:
                    ch = loop._channels.get(kind)
                    if ch is not None:
                        ch.last_arrival_s, ch.errors_in_row = now, 0
                for kind in self.kinds:
                    loop._channels[kind].take()
            else:
                self._aligner = None
                self.armed = False
            loop._aligner = Aligner(max_wait_s=loop.max_align_wait_s)

    def judged(self, ch: Any) -> bool:
        """Whether a channel's errors and staleness trip now: the second axis's only during a turning test, the
        angle channel's not then (the pairs are the time base)."""
        if ch.kind in SECOND_AXIS:
            return self.active
        return not (self.active and ch.kind == "angle")

    # -- stepping -------------------------------------------------------------------------------------------------
    def step(self, torque: Batch, now: float) -> bool:
        """One step of the loop with the torque batch it took: outside a turning test drain the second axis and
        return False (the stiffness path publishes); during one align and publish the pairs, return True."""
        loop = self.loop
        if not self.active or self._aligner is None:
            for kind in self.kinds:
                loop._channels[kind].take()  # read (a FIFO drained), not used outside a turning test
            return False
        pair, pair_extra = loop._channels["input_angle"].take()
        side = {"torque_nm": (torque.time_s, torque.value)}
        if "input_torque" in loop._channels:
            tin, _ = loop._channels["input_torque"].take()
            side["input_torque_nm"] = (tin.time_s, tin.value)
        inputs = pair_extra.get(INPUT_ANGLE_COLUMN)
        if len(pair) and inputs is None:
            raise TcmsError(f"{loop._channels['input_angle'].name}: its readings carry no input angle "
                            f"({INPUT_ANGLE_COLUMN}): not an angle pair source")
        cols = self._aligner.push(pair.time_s, pair.value, inputs if inputs is not None else np.empty(0), side, now)
        if cols:
            self._publish(cols)
        return True

    def flush(self) -> bool:
        """At the loop's stop: publish the held pairs (True) during a turning test; False otherwise."""
        if not self.active or self._aligner is None:
            return False
        cols = self._aligner.flush()
        if cols:
            self._publish(cols)
        return True

    def _publish(self, cols: dict[str, np.ndarray]) -> None:
        raw = cols.pop("output_arcsec")
        self.loop._publish(cols.pop("time_s"), cols.pop("torque_nm"), raw, cols)

    # -- the input drive ------------------------------------------------------------------------------------------
    def poll_drive(self, *, wait_for_lock: bool = True) -> InputDriveStatus | None:
        """Read the input drive's status (under its lock), as the loop's ``poll_status`` the loader's; while a turning
        test has armed it, a drive in FAULT trips ``drive_fault`` naming the input drive."""
        loop = self.loop
        ch = loop._channels.get("input_drive")
        drive = loop.bench.input_drive
        if ch is None or drive is None:
            return None
        if not self.drive_lock.acquire(blocking=wait_for_lock):
            return None
        ch.busy_since = loop.clock.now()
        try:
            status = drive.status()
        except InstrumentError as exc:
            loop._on_error(ch, exc)
            return None
        except Exception as exc:
            loop._on_error(ch, Disconnected(ch.name, f"{type(exc).__name__}: {exc}"))
            return None
        finally:
            ch.busy_since = None
            self.drive_lock.release()
        ch.errors_in_row = 0
        ch.readings += 1
        ch.last_arrival_s = loop.clock.now()
        ch.last_arrival_real_s = time.monotonic()
        self.last_status = status
        if self.armed and self.active and (status.fault or status.state.upper() == "FAULT"):
            code = f" 0x{status.error_code:04X}" if status.error_code else ""
            loop.raise_trip(Trip("drive_fault", f"input drive fault{code} ({ch.name} state {status.state})",
                                 loop.clock.now()))
        return status

    def drive_command(self, fn: Callable[..., Any], *args: Any) -> Any:
        """Call an input drive method under its lock (the status poller uses the same driver); a failure trips as a
        loader command's does, naming the input drive, and is re-raised."""
        loop = self.loop
        ch = loop._channels["input_drive"]
        with self.drive_lock:
            ch.busy_since = loop.clock.now()
            try:
                return fn(*args)
            except InstrumentError as exc:
                loop._on_error(ch, exc)
                loop.raise_trip(loop._command_trip("input_drive", exc))
                raise
            finally:
                ch.busy_since = None

    def link_failing(self) -> str | None:
        """Why the input drive's link looks lost (its last requests failed), None when it answers."""
        ch = self.loop._channels.get("input_drive")
        if ch is None or not ch.errors_in_row:
            return None
        return f"{ch.errors_in_row} failed request(s): {ch.last_error}"

    def latest_input_angle_arcsec(self) -> float | None:
        """The angle pair source's latest input angle (input arcsec); None without one or before a reading."""
        ch = self.loop._channels.get("input_angle")
        return None if ch is None else ch.last_input_arcsec

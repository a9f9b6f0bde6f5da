"""CiA 402 drive semantics shared by the CANopen and Modbus loader drivers (protocols.md §3.1–3.2).

Statusword decoding, the controlword commands, torque scaling (‰ of the motor rated torque 0x6076), the
validation of torque commands before any byte leaves, and ``CiA402Loader``: the Loader logic (state walk,
ramp-down, status) that both transports share.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, Self

from tcms_daq.drivers.base import (
    Clock,
    CommandRejected,
    DeviceFault,
    Disconnected,
    InstrumentTimeout,
    LoaderStatus,
)
from tcms_daq.drivers.options import CiA402Options, VelocityDriveOptions
from tcms_daq.drivers.timebase import REAL_TIME, Timebase

from tcms_daq.protocols.cia402 import (
    CW_DISABLE_VOLTAGE,
    CW_ENABLE_OPERATION,
    CW_FAULT_RESET,
    CW_NEW_SET_POINT,
    CW_QUICK_STOP,
    CW_SHUTDOWN,
    CW_SWITCH_ON,
    MODE_PROFILE_POSITION,
    MODE_PROFILE_TORQUE,
    STATE_PATTERN,
    SW_SET_POINT_ACK,
    SW_TARGET_REACHED,
    is_fault,
    state_from_statusword,
)


class TorqueScaling:
    """Converts between N·m and the drive's ‰-of-rated units and validates commands against the limits.

    rated_torque_nm: the drive's motor rated torque (0x6076); max_torque_nm: the bench/loader limit a command
    may never exceed (defaults to the largest INT16 ‰ value the protocol can carry).
    """

    def __init__(self, instrument: str, rated_torque_nm: float, max_torque_nm: float | None = None):
        if not (math.isfinite(rated_torque_nm) and rated_torque_nm > 0):
            raise CommandRejected(instrument, f"rated torque must be > 0 N·m, got {rated_torque_nm}")
        self.instrument = instrument
        self.rated_torque_nm = float(rated_torque_nm)
        protocol_limit = 32767 / 1000.0 * self.rated_torque_nm
        self.max_torque_nm = protocol_limit if max_torque_nm is None else min(float(max_torque_nm), protocol_limit)

    def permille(self, torque_nm: float) -> int:
        return round(torque_nm / self.rated_torque_nm * 1000.0)

    def newton_metres(self, permille: int) -> float:
        return permille / 1000.0 * self.rated_torque_nm

    def target_permille(self, target_nm: float) -> int:
        """The INT16 ‰ value for a target torque; CommandRejected (nothing sent) beyond the limit."""
        if not isinstance(target_nm, int | float) or not math.isfinite(target_nm):
            raise CommandRejected(self.instrument, f"target torque must be a finite number of N·m, got {target_nm!r}")
        if abs(target_nm) > self.max_torque_nm + 1e-9:
            raise CommandRejected(
                self.instrument,
                f"target torque {target_nm:g} N·m exceeds the limit ±{self.max_torque_nm:g} N·m",
            )
        return self.permille(target_nm)

    def slope_permille_per_s(self, slope_nm_per_s: float) -> int:
        if not isinstance(slope_nm_per_s, int | float) or not math.isfinite(slope_nm_per_s) or slope_nm_per_s <= 0:
            raise CommandRejected(self.instrument, f"torque slope must be > 0 N·m/s, got {slope_nm_per_s!r}")
        value = round(slope_nm_per_s / self.rated_torque_nm * 1000.0)
        if not 1 <= value <= 0xFFFFFFFF:
            raise CommandRejected(self.instrument, f"torque slope {slope_nm_per_s:g} N·m/s is out of range")
        return value


class CiA402Wire:
    """What a transport gives the CiA 402 state machine (:class:`CiA402Loader`): one primitive per wire access —
    read the statusword, error code, torque, process data and mode display; write a setting, the target, the
    controlword; wait for a statusword. CANopen maps them onto SDO/PDO (``drivers.cia402_canopen``), Modbus onto
    registers (``drivers.cia402_modbus``). Torque in ‰ of the rated torque, as on the wire."""

    def _ensure_ready(self) -> None:
        """Before a command: re-establish a lost link (bounded) or raise Disconnected."""

    def _stop_link_degraded(self) -> str | None:
        """Before a stop command (disable, quick stop): the reason the link cannot confirm it, else None.
        A degraded link still gets the stop commands (the drive may hear them); the method then raises."""
        return None

    def _read_statusword(self) -> int:
        raise NotImplementedError

    def _read_error_code(self) -> int:
        raise NotImplementedError

    def _read_torque_permille(self) -> int:
        raise NotImplementedError

    def _read_process(self) -> tuple[int, int, int]:
        """(statusword, torque actual ‰, position actual counts)."""
        raise NotImplementedError

    def _read_mode_display(self) -> int:
        raise NotImplementedError

    def _write_setting(self, name: str, value: int) -> None:
        """Write one drive setting: ``max_torque`` (‰), ``torque_slope`` (‰/s) or ``mode``."""
        raise NotImplementedError

    def _write_target(self, permille: int) -> None:
        """Send a new target torque (‰) now."""
        raise NotImplementedError

    def _reset_target(self) -> None:
        """Make the target 0 ‰ before a state change (at once, or with the next controlword)."""
        self._write_target(0)

    def _write_controlword(self, controlword: int) -> float | None:
        """Send a controlword; returns a marker for ``_await_statusword`` (e.g. the time it was sent)."""
        raise NotImplementedError

    def _await_statusword(self, predicate: Callable[[int], bool], since: float | None,
                          timeout_s: float) -> tuple[int | None, int]:
        """(the first statusword after ``since`` satisfying ``predicate`` or None after ``timeout_s``,
        the last statusword seen)."""
        raise NotImplementedError


class CiA402Drive(CiA402Wire):
    """What every CiA 402 drive of the bench shares above its transport: the state walk, fault handling, quick stop,
    fault reset and the rated torque (0x6076) scaling. The loader (:class:`CiA402Loader`, profile torque) and the
    input drive (``drivers.cia402_velocity``, profile velocity) build on it; a transport class (CANopen, Modbus)
    provides the primitives of :class:`CiA402Wire`."""

    name: str
    scaling: TorqueScaling | None

    def __init__(self, options: CiA402Options | VelocityDriveOptions, *, clock: Clock,
                 timebase: Timebase = REAL_TIME):
        self.options = options
        self.name = options.name
        self.url = options.url
        self.state_timeout_s = float(options.state_timeout_s)
        self.clock = clock
        self.timebase = timebase
        self.scaling = None
        self.max_torque_nm: float | None = None
        self._slope_permille: int | None = None  # last slope written to the drive (None: unknown)
        self.counts_per_rev = options.counts_per_rev

    def _configure_scaling(self, rated_torque_mnm: int) -> None:
        """Set up the torque scaling from the drive's rated torque (0x6076, mN·m) after (re)connecting."""
        self.scaling = TorqueScaling(self.name, rated_torque_mnm / 1000.0, self.max_torque_nm)
        self._slope_permille = None

    def _scaling(self) -> TorqueScaling:
        if self.scaling is None:
            raise Disconnected(self.name, "not connected; call connect() first")
        return self.scaling

    @property
    def rated_torque_nm(self) -> float:
        return self._scaling().rated_torque_nm

    def _raise_if_fault(self, statusword: int, doing: str) -> None:
        if is_fault(statusword):
            code = self._read_error_code()
            raise DeviceFault(self.name, f"{doing}: drive in FAULT, error code 0x{code:04X}", code=code)

    def _command(self, controlword: int, target_state: str, *, stop_on_fault: bool = True) -> None:
        """Send ``controlword`` and wait (``state_timeout_s``) for the statusword of ``target_state``."""
        mask, value = STATE_PATTERN[target_state]
        since = self._write_controlword(controlword)
        found, last = self._await_statusword(lambda sw: sw & mask == value or (stop_on_fault and is_fault(sw)),
                                             since, self.state_timeout_s)
        if found is None:
            self._raise_if_fault(last, f"waiting for {target_state}")
            raise InstrumentTimeout(self.name, f"drive did not reach {target_state} within {self.state_timeout_s:g} s "
                                    f"(statusword 0x{last:04X}: {state_from_statusword(last)})")
        self._raise_if_fault(found, f"waiting for {target_state}")

    def _walk_to_enabled(self, statusword: int) -> None:
        """From the state of ``statusword`` (the mode already set) to OPERATION ENABLED: 0x06 → 0x07 → 0x0F."""
        state = state_from_statusword(statusword)
        if state == "OPERATION ENABLED":
            self._write_controlword(CW_ENABLE_OPERATION)
            return
        if state not in ("READY TO SWITCH ON", "SWITCHED ON"):
            self._command(CW_SHUTDOWN, "READY TO SWITCH ON")
        if state != "SWITCHED ON":
            self._command(CW_SWITCH_ON, "SWITCHED ON")
        self._command(CW_ENABLE_OPERATION, "OPERATION ENABLED")

    def quick_stop(self) -> None:
        """Quick stop (controlword 0x000B, target 0): the drive ramps down with its quick-stop ramp and, with
        quick-stop option 1/2, ends in SWITCH ON DISABLED."""
        degraded = self._stop_link_degraded()
        self._reset_target()
        self._write_controlword(CW_QUICK_STOP)
        self._raise_unconfirmed("quick stop", degraded)

    def _raise_unconfirmed(self, what: str, degraded: str | None) -> None:
        if degraded is not None:
            raise Disconnected(self.name, f"{what} sent on a degraded link ({degraded}); not confirmed")

    def fault_reset(self) -> None:
        """Controlword bit 7 low, then high (a rising edge): FAULT → SWITCH ON DISABLED."""
        self._ensure_ready()
        self._reset_target()
        self._write_controlword(CW_DISABLE_VOLTAGE)
        self._command(CW_FAULT_RESET, "SWITCH ON DISABLED", stop_on_fault=False)

    def connect(self) -> None:
        raise NotImplementedError

    def close(self) -> None:
        raise NotImplementedError

    def __enter__(self) -> Self:
        self.connect()
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


class CiA402Loader(CiA402Drive):
    """The transport-independent half of a CiA 402 loader (``drivers.base.Loader``): validation, the state
    walk to OPERATION ENABLED in profile torque mode, torque scaling, status decoding, the ramp-down on disable.

    A transport subclass (CANopen SDO/PDO, Modbus registers) provides the primitives of :class:`CiA402Wire`; everything a
    method validates is checked before its first primitive is called, so a rejected command sends nothing.
    Torque in N·m at this interface, ‰ of the rated torque on the wire; positive torque twists positive.
    """

    options: CiA402Options

    def __init__(self, options: CiA402Options, *, clock: Clock, timebase: Timebase = REAL_TIME):
        super().__init__(options, clock=clock, timebase=timebase)
        self.max_torque_nm = options.max_torque_nm
        self.default_slope_nm_per_s = float(options.torque_slope_nm_per_s)
        # profile position (moves between the positions of a multi-position test): position actual 0x6064 and
        # target 0x607A count this many per revolution of the output; a move is refused above the torque window
        # (None: 1 % of the rated torque)
        self.move_torque_window_nm: float | None = options.move_torque_window_nm
        self._position_mode = False  # a move was started and enable() has not returned to profile torque

    def _set_slope(self, slope_permille: int) -> None:
        if slope_permille != self._slope_permille:
            self._write_setting("torque_slope", slope_permille)
            self._slope_permille = slope_permille

    def move_to(self, position_deg: float, velocity_deg_per_s: float) -> None:
        """Profile position (mode 1): turn the output to ``position_deg`` at ``velocity_deg_per_s`` and return once
        the drive acknowledged the set-point (``status().moving`` until bit 10 target reached). Refused
        (CommandRejected, nothing sent but reads) unless OPERATION ENABLED with the torque actual within the
        window: no move under torque. ``enable()`` returns to profile torque at zero."""
        scaling = self._scaling()
        for name, value in (("position", position_deg), ("velocity", velocity_deg_per_s)):
            if not isinstance(value, int | float) or not math.isfinite(value):
                raise CommandRejected(self.name, f"move: {name} must be a finite number, got {value!r}")
        if velocity_deg_per_s <= 0:
            raise CommandRejected(self.name, f"move: velocity must be > 0 deg/s, got {velocity_deg_per_s:g}")
        counts = round(position_deg / 360.0 * self.counts_per_rev)
        velocity_counts = max(1, round(velocity_deg_per_s / 360.0 * self.counts_per_rev))
        if not -(1 << 31) <= counts < (1 << 31) or velocity_counts > 0xFFFFFFFF:
            raise CommandRejected(self.name, f"move to {position_deg:g}° at {velocity_deg_per_s:g}°/s is out of range")
        self._ensure_ready()
        sw, torque_permille, _ = self._read_process()
        self._raise_if_fault(sw, "move")
        if state_from_statusword(sw) != "OPERATION ENABLED":
            raise CommandRejected(self.name, f"move: drive in {state_from_statusword(sw)}, not OPERATION ENABLED")
        torque_nm = scaling.newton_metres(torque_permille)
        window = self.move_torque_window_nm if self.move_torque_window_nm is not None else 0.01 * scaling.rated_torque_nm
        if abs(torque_nm) > window:
            raise CommandRejected(self.name, f"{torque_nm:.3g} N·m on the output: no move under torque "
                                  f"(window ±{window:g} N·m)")
        self._reset_target()
        self._write_setting("mode", MODE_PROFILE_POSITION)
        shown = self._read_mode_display()
        if shown != MODE_PROFILE_POSITION:
            raise CommandRejected(self.name, f"drive shows mode {shown} (mode display), not profile position (1)")
        self._position_mode = True
        self._write_setting("profile_velocity", velocity_counts)
        self._write_setting("target_position", counts)
        self._write_controlword(CW_ENABLE_OPERATION)
        since = self._write_controlword(CW_ENABLE_OPERATION | CW_NEW_SET_POINT)  # rising edge of bit 4
        found, last = self._await_statusword(lambda word: bool(word & SW_SET_POINT_ACK) or is_fault(word), since,
                                             self.state_timeout_s)
        self._write_controlword(CW_ENABLE_OPERATION)  # bit 4 back low for the next set-point
        if found is None:
            raise InstrumentTimeout(self.name, f"the drive did not acknowledge the move to {position_deg:g}° "
                                    f"(statusword 0x{last:04X})")
        self._raise_if_fault(found, "move")

    def enable(self) -> None:
        """Profile torque mode (4) with target 0, then 0x06 → 0x07 → 0x0F to OPERATION ENABLED; DeviceFault if
        the drive is in FAULT (reset it first), CommandRejected if the mode does not take."""
        self._ensure_ready()
        scaling = self._scaling()
        sw = self._read_statusword()
        self._raise_if_fault(sw, "enable")
        self._reset_target()
        if self.max_torque_nm is not None:
            self._write_setting("max_torque", min(0xFFFF, scaling.permille(scaling.max_torque_nm)))
        self._set_slope(scaling.slope_permille_per_s(self.default_slope_nm_per_s))
        self._write_setting("mode", MODE_PROFILE_TORQUE)
        shown = self._read_mode_display()
        if shown != MODE_PROFILE_TORQUE:
            raise CommandRejected(self.name, f"drive shows mode {shown} (mode display), not profile torque (4)")
        self._position_mode = False
        self._walk_to_enabled(sw)

    def set_torque(self, target_nm: float, slope_nm_per_s: float | None = None) -> None:
        scaling = self._scaling()
        permille = scaling.target_permille(target_nm)
        slope = scaling.slope_permille_per_s(self.default_slope_nm_per_s if slope_nm_per_s is None else slope_nm_per_s)
        self._ensure_ready()
        self._set_slope(slope)
        self._write_target(permille)

    def disable(self) -> None:
        """Target 0 (ramped), wait (bounded) for the torque to come down, then disable voltage. The disable
        voltage is sent even if the wait fails; on a degraded link both go out at once and Disconnected follows."""
        scaling = self._scaling()
        degraded = self._stop_link_degraded()
        self._write_target(0)
        try:
            if degraded is None and state_from_statusword(self._read_statusword()) == "OPERATION ENABLED":
                slope_nm_per_s = scaling.newton_metres(self._slope_permille or 1000)
                actual_nm = abs(scaling.newton_metres(self._read_torque_permille()))
                deadline = self.timebase.now() + min(10.0, actual_nm / max(slope_nm_per_s, 1e-9) + 0.5)
                while self.timebase.now() < deadline and abs(self._read_torque_permille()) > 5:
                    self.timebase.sleep(0.01)
        finally:
            self._write_controlword(CW_DISABLE_VOLTAGE)
        self._raise_unconfirmed("disable", degraded)

    def status(self) -> LoaderStatus:
        self._ensure_ready()
        scaling = self._scaling()
        time_s = self.clock()
        sw, torque_permille, position = self._read_process()
        fault = is_fault(sw)
        state = state_from_statusword(sw)
        return LoaderStatus(
            state=state,
            torque_actual_nm=scaling.newton_metres(torque_permille),
            fault=fault,
            error_code=self._read_error_code() if fault else 0,
            position_counts=position,
            time_s=time_s,
            position_deg=position / self.counts_per_rev * 360.0,
            moving=self._position_mode and state == "OPERATION ENABLED" and not sw & SW_TARGET_REACHED,
        )

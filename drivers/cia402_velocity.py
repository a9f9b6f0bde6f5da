"""The second axis's input drive: a CiA 402 drive in profile velocity (mode 3) over CANopen or Modbus: InputDrive.

The drive turns the reducer's input at a target velocity 0x60FF with the profile acceleration/deceleration
0x6083/0x6084; velocity actual 0x606C and position actual 0x6064 say what it does. Velocities here are deg/s at the
input shaft, on the wire counts/s of ``counts_per_rev`` (the drive's position encoder per input revolution; a real
drive's velocity unit may be scaled otherwise by its factor group: configure ``counts_per_rev`` so that 0x606C reads
counts/s of it). It shares the loader's transports and safety:

- CANopen (``cia402-velocity-canopen``): on the loader's bus at its own node id (default 2), its own EDS
  (``drive402-velocity.eds``: RPDO1 = controlword + 0x60FF, TPDO1 = statusword + 0x606C, TPDO2 = mode display + error
  code + 0x6064); its own link's master heartbeat (node id 0x7E by default) is watched by the drive's heartbeat
  consumer 0x1016: a dead service or a silent link makes the drive react by itself (0x6007: fault 0x8130).
- Modbus (``cia402-velocity-modbus``): TCP or RTU at its own unit id (the packaged ``modbus-input-drive.toml``:
  device id 2), the drive's communication timeout armed on connect and fed by a keep-alive thread, as the loader's.

``enable()`` writes the ramps and the speed limit (0x607F), profile velocity mode with target 0, reads the mode
display back, then walks 0x06 → 0x07 → 0x0F; ``disable()`` commands 0, waits (bounded by the ramp) for the shaft
to stop, then disables voltage; ``quick_stop()`` stops with the quick-stop deceleration 0x6085. A command above the
limit is refused before any byte leaves. The torque methods of the loader are not offered (CommandRejected).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from pathlib import Path

from tcms_daq.drivers.base import Clock, CommandRejected, InputDriveStatus
from tcms_daq.drivers.canopen_link import VELOCITY_LAYOUT, PdoLayout
from tcms_daq.drivers.cia402 import CiA402Drive
from tcms_daq.drivers.cia402_canopen import CanopenWire
from tcms_daq.drivers.cia402_modbus import ModbusWire
from tcms_daq.drivers.options import (
    CiA402VelocityCanopenOptions,
    CiA402VelocityModbusOptions,
    VelocityDriveOptions,
)
from tcms_daq.drivers.timebase import REAL_TIME, Timebase

from tcms_daq.protocols.cia402 import (
    CW_DISABLE_VOLTAGE,
    MODE_PROFILE_VELOCITY,
    is_fault,
    state_from_statusword,
    velocity_drive_eds_path,
)
from tcms_daq.protocols.modbus_map import INPUT_DRIVE_MAP_PATH, VELOCITY_REGISTERS, RegisterMap

INT32_MAX = (1 << 31) - 1


class CiA402VelocityDrive(CiA402Drive):
    """The transport-independent half of the input drive (``drivers.base.InputDrive``): validation, the state walk
    to OPERATION ENABLED in profile velocity, scaling deg/s ↔ counts/s, the ramp-down on disable. A transport class
    (:class:`CanopenWire`, :class:`ModbusWire`) provides the primitives; the actual of its process data
    (``_read_process``) is the velocity actual 0x606C."""

    options: VelocityDriveOptions

    def __init__(self, options: VelocityDriveOptions, *, clock: Clock, timebase: Timebase = REAL_TIME):
        super().__init__(options, clock=clock, timebase=timebase)
        self.max_velocity_deg_per_s = float(options.max_velocity_deg_per_s)
        self.velocity_window_deg_per_s = float(options.velocity_window_deg_per_s)

    # -- scaling -----------------------------------------------------------------------------------------

    def counts_per_s(self, velocity_deg_per_s: float) -> int:
        return round(velocity_deg_per_s / 360.0 * self.counts_per_rev)

    def deg_per_s(self, counts_per_s: int) -> float:
        return counts_per_s / self.counts_per_rev * 360.0

    def _unsigned_counts(self, deg_per_s: float, what: str) -> int:
        value = self.counts_per_s(deg_per_s)
        if not 1 <= value <= INT32_MAX:
            raise CommandRejected(self.name, f"{what} {deg_per_s:g} deg/s is out of range for "
                                  f"{self.counts_per_rev} counts/rev")
        return value

    # -- InputDrive ----------------------------------------------------------------------------------------

    def enable(self) -> None:
        """Ramps, speed limit, profile velocity mode (3) at target 0, then to OPERATION ENABLED; DeviceFault if the
        drive is in FAULT (reset it first), CommandRejected if the mode does not take."""
        options = self.options
        settings = {
            "max_profile_velocity": self._unsigned_counts(self.max_velocity_deg_per_s, "max velocity"),
            "profile_acceleration": self._unsigned_counts(options.acceleration_deg_per_s2, "acceleration"),
            "profile_deceleration": self._unsigned_counts(options.acceleration_deg_per_s2, "deceleration"),
            "quick_stop_deceleration": self._unsigned_counts(options.quick_stop_deceleration_deg_per_s2,
                                                             "quick-stop deceleration"),
        }
        self._ensure_ready()
        sw = self._read_statusword()
        self._raise_if_fault(sw, "enable")
        self._reset_target()
        for name, value in settings.items():
            self._write_setting(name, value)
        self._write_setting("mode", MODE_PROFILE_VELOCITY)
        shown = self._read_mode_display()
        if shown != MODE_PROFILE_VELOCITY:
            raise CommandRejected(self.name, f"drive shows mode {shown} (mode display), not profile velocity (3)")
        self._walk_to_enabled(sw)

    def set_velocity(self, velocity_deg_per_s: float) -> None:
        """Target velocity at the input shaft (deg/s); CommandRejected (nothing sent) if not finite or above
        ``max_velocity_deg_per_s``."""
        if not isinstance(velocity_deg_per_s, int | float) or not math.isfinite(velocity_deg_per_s):
            raise CommandRejected(self.name, f"velocity must be a finite number of deg/s, got {velocity_deg_per_s!r}")
        if abs(velocity_deg_per_s) > self.max_velocity_deg_per_s + 1e-9:
            raise CommandRejected(self.name, f"velocity {velocity_deg_per_s:g} deg/s exceeds the limit "
                                  f"±{self.max_velocity_deg_per_s:g} deg/s")
        self._ensure_ready()
        self._write_target(self.counts_per_s(velocity_deg_per_s))

    def disable(self) -> None:
        """Target 0 (ramped by the drive's deceleration), wait (bounded) for the shaft to come to rest, then disable
        voltage. The disable voltage is sent even if the wait fails; on a degraded link both go out at once and
        Disconnected follows."""
        degraded = self._stop_link_degraded()
        self._write_target(0)
        try:
            if degraded is None:
                sw, velocity, _ = self._read_process()
                if state_from_statusword(sw) == "OPERATION ENABLED":
                    wait_s = abs(self.deg_per_s(velocity)) / self.options.acceleration_deg_per_s2 + 0.5
                    deadline = self.timebase.now() + min(10.0, wait_s)
                    while (self.timebase.now() < deadline
                           and abs(self.deg_per_s(self._read_process()[1])) > self.velocity_window_deg_per_s):
                        self.timebase.sleep(0.01)
        finally:
            self._write_controlword(CW_DISABLE_VOLTAGE)
        self._raise_unconfirmed("disable", degraded)

    def status(self) -> InputDriveStatus:
        self._ensure_ready()
        time_s = self.clock()
        sw, velocity, position = self._read_process()
        fault = is_fault(sw)
        return InputDriveStatus(state=state_from_statusword(sw), velocity_deg_per_s=self.deg_per_s(velocity),
                                fault=fault, error_code=self._read_error_code() if fault else 0,
                                position_deg=position / self.counts_per_rev * 360.0, time_s=time_s)

    def set_torque(self, target_nm: float, slope_nm_per_s: float | None = None) -> None:
        raise CommandRejected(self.name, "an input drive in profile velocity takes velocities (set_velocity), "
                              "not torques")


class CiA402VelocityCanopen(CanopenWire, CiA402VelocityDrive):
    """InputDrive over CANopen (``driver = "cia402-velocity-canopen"``)."""

    options_model = CiA402VelocityCanopenOptions
    options: CiA402VelocityCanopenOptions
    pdo_layout: PdoLayout = VELOCITY_LAYOUT
    default_eds: Callable[[], Path] = staticmethod(velocity_drive_eds_path)

    def __init__(self, options: CiA402VelocityCanopenOptions, *, clock: Clock = time.monotonic,
                 timebase: Timebase = REAL_TIME):
        super().__init__(options, clock=clock, timebase=timebase)


class CiA402VelocityModbus(ModbusWire, CiA402VelocityDrive):
    """InputDrive over Modbus TCP/RTU (``driver = "cia402-velocity-modbus"``)."""

    options_model = CiA402VelocityModbusOptions
    options: CiA402VelocityModbusOptions
    default_register_map = INPUT_DRIVE_MAP_PATH
    required_registers = VELOCITY_REGISTERS

    def __init__(self, options: CiA402VelocityModbusOptions, *, clock: Clock = time.monotonic,
                 timebase: Timebase = REAL_TIME, register_map: RegisterMap | None = None,
                 trace_packet: Callable[[bool, bytes], bytes] | None = None):
        super().__init__(options, clock=clock, timebase=timebase, register_map=register_map,
                         trace_packet=trace_packet)

    def _read_process(self) -> tuple[int, int, int]:
        return (self.link.read_register("statusword"), self.link.read_register("velocity_actual"),
                self.link.read_register("position_actual"))

    def _write_target(self, permille: int) -> None:
        self.link.write_register("target_velocity", permille)

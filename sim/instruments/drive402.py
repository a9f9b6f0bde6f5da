"""A CiA 402 servo drive in profile torque mode, driving the shared bench physics.

One model, two front ends (``drive_modbus``, ``drive_canopen``); both call into it under the physics lock.
State machine (protocols.md §3.1): controlword commands shutdown / switch on / enable operation / disable
voltage / quick stop, fault reset on the **rising edge** of bit 7 only. Statusword is computed, never stored.

Profile torque (mode 4): in OPERATION ENABLED the target torque 0x6071 (‰ of the rated torque 0x6076),
clamped by max torque 0x6072 (statusword bit 11 "internal limit active" while clamping), is handed to the
bench as a ramp with slope 0x6087 (‰/s). Torque actual 0x6077 and position actual 0x6064 come from the
physics (applied motor torque, true output twist in counts of ``counts_per_rev``). Bit 10 "target reached"
when |actual − effective target| ≤ ``target_window_permille``.

Safety: quick stop (option 0x605A = 2: ramp to zero with the quick-stop slope, then SWITCH ON DISABLED;
5…8: stay in QUICK STOP ACTIVE); a fault (``inject_fault(code)``) goes FAULT REACTION ACTIVE → FAULT with the
torque removed at once, sets 0x603F/0x1001 and notifies the EMCY listeners; leaving FAULT sends the EMCY error
reset (code 0). The communication watchdog (``communication_lost()``, called by a front end whose master went
silent: CANopen heartbeat consumer, Modbus communication timeout ``comm_timeout_ms``) reacts as the abort
connection option code 0x6007 says: 1 fault 0x8130 (the default), 2 disable voltage, 3 quick stop, 0 nothing.

Profile position (mode 1, 0x6502 = 0x0009 with mode 4): in OPERATION ENABLED a rising edge of controlword bit 4
(new set-point) turns the output to the target position 0x607A (counts of ``counts_per_rev`` per output
revolution) at the profile velocity 0x6081 (counts/s), with no torque applied; statusword bit 12 acknowledges the
set-point while bit 4 is held, bit 10 "target reached" once the output rests within ``position_window_counts``.
Leaving OPERATION ENABLED or mode 1 (disable, quick stop, fault) halts a move where the output is.
"""

from __future__ import annotations

import enum
import functools
import math
from collections.abc import Callable

from tcms_daq.sim.instruments.drivetrain import DriveTrainPhysics
from tcms_daq.sim.instruments.physics import PhysicsReading, SharedPhysics

from tcms_daq.protocols.cia402 import (
    ABORT_CONNECTION_DISABLE_VOLTAGE,
    ABORT_CONNECTION_FAULT,
    ABORT_CONNECTION_OPTIONS,
    ABORT_CONNECTION_QUICK_STOP,
    CW_NEW_SET_POINT,
    EMCY_COMMUNICATION,
    MODE_PROFILE_POSITION,
    MODE_PROFILE_TORQUE,
    MODE_PROFILE_VELOCITY,
    SUPPORTED_MODES,
    SUPPORTED_MODES_VELOCITY,
    SW_SET_POINT_ACK,
    SW_TARGET_REACHED,
    to_int16,
)
from tcms_daq.units import ARCSEC_PER_REV

ERROR_REGISTER_FOR = {0x2: 0x02, 0x3: 0x04, 0x4: 0x08, 0x8: 0x10, 0x7: 0x80}  # by the code's first hex digit


class State(enum.Enum):
    NOT_READY_TO_SWITCH_ON = 0x0000
    SWITCH_ON_DISABLED = 0x0040
    READY_TO_SWITCH_ON = 0x0031
    SWITCHED_ON = 0x0033
    OPERATION_ENABLED = 0x0037
    QUICK_STOP_ACTIVE = 0x0017
    FAULT_REACTION_ACTIVE = 0x001F
    FAULT = 0x0018

    @property
    def label(self) -> str:
        return self.name.replace("_", " ")


class DriveCommandError(ValueError):
    """A write the drive refuses (value out of range, read-only object, not possible in this state)."""

    def __init__(self, message: str, *, kind: str = "range"):
        super().__init__(message)
        self.kind = kind  # "range" | "readonly" | "state" | "unknown"


EmcyListener = Callable[[int, int], None]  # (error code, error register)


class Drive402Model:
    """The drive; every public method takes the shared physics lock. The front ends reach its objects through
    ``od_getters``/``od_setters`` (CANopen, by index), ``register_getters``/``register_setters`` (Modbus, by the
    register map's names), ``write_rpdo`` and ``process_values`` (the PDOs)."""

    supported_modes = SUPPORTED_MODES

    def __init__(
        self,
        physics: SharedPhysics,
        *,
        rated_torque_mnm: int = 2_000_000,
        max_torque_permille: int = 1000,
        torque_slope_permille_per_s: int = 1000,
        quick_stop_slope_permille_per_s: int = 10_000,
        quick_stop_option: int = 2,
        target_window_permille: int = 5,
        counts_per_rev: int = 1 << 20,
        comm_timeout_ms: int = 1000,
        abort_connection_option: int = ABORT_CONNECTION_FAULT,
    ):
        self.physics = physics
        # the communication watchdog's settings (Modbus: the comm timeout register; 0 = off) and reaction (0x6007);
        # factory defaults, kept over a power cycle (a real drive stores them)
        self.comm_timeout_ms = int(comm_timeout_ms)
        self.abort_connection_option = int(abort_connection_option)
        self.lock = physics.lock
        self.rated_torque_mnm = int(rated_torque_mnm)
        self.max_torque_permille = int(max_torque_permille)
        self.torque_slope_permille_per_s = int(torque_slope_permille_per_s)
        self.quick_stop_slope_permille_per_s = int(quick_stop_slope_permille_per_s)
        self.quick_stop_option = int(quick_stop_option)
        self.target_window_permille = int(target_window_permille)
        self.counts_per_rev = int(counts_per_rev)
        self.position_window_counts = max(1, self.counts_per_rev // 36_000)  # 0.01° of the output
        self._power_on_state()
        self._emcy_listeners: list[EmcyListener] = []
        self._latest = physics.latest()
        physics.add_tick_hook(self._on_tick)
        self._init_physics()

    def _init_physics(self) -> None:
        """The drive is off at power-on: the loader applies nothing."""
        self.physics.set_drive_enabled(False)

    def power_cycle(self) -> None:
        """Restart the drive: SWITCH ON DISABLED, no mode, zero target, errors cleared, torque off."""
        with self.lock:
            self._power_on_state()
            self._apply()

    def _power_on_state(self) -> None:
        self.state = State.SWITCH_ON_DISABLED  # transitions 0 and 1 happen at power-on
        self.controlword = 0
        self.mode = 0
        self.target_torque_permille = 0
        self.target_position_counts = 0
        self.profile_velocity_counts_per_s = 10_000
        self.error_code = 0
        self.error_register = 0

    def detach(self) -> None:
        self.physics.remove_tick_hook(self._on_tick)

    def add_emcy_listener(self, listener: EmcyListener) -> None:
        with self.lock:
            self._emcy_listeners.append(listener)

    def remove_emcy_listener(self, listener: EmcyListener) -> None:
        with self.lock:
            if listener in self._emcy_listeners:
                self._emcy_listeners.remove(listener)

    # -- derived values --------------------------------------------------------------------------------

    @property
    def rated_torque_nm(self) -> float:
        return self.rated_torque_mnm / 1000.0

    def _effective_target_permille(self) -> int:
        return max(-self.max_torque_permille, min(self.max_torque_permille, self.target_torque_permille))

    def torque_actual_permille(self) -> int:
        with self.lock:
            value = round(self._latest.applied_torque_nm / self.rated_torque_nm * 1000.0)
            return max(-32768, min(32767, value))

    def position_counts(self) -> int:
        with self.lock:
            value = round(self._latest.true_angle_arcsec / ARCSEC_PER_REV * self.counts_per_rev)
            return max(-(1 << 31), min((1 << 31) - 1, value))

    def mode_display(self) -> int:
        return self.mode

    def statusword(self) -> int:
        with self.lock:
            word = self.state.value | 0x0200  # bit 9 remote
            if self.state is State.OPERATION_ENABLED and self.mode == MODE_PROFILE_POSITION:
                if (not self.physics.output_moving()
                        and abs(self.position_counts() - self.target_position_counts) <= self.position_window_counts):
                    word |= SW_TARGET_REACHED
                if self.controlword & CW_NEW_SET_POINT:
                    word |= SW_SET_POINT_ACK
            if self.state is State.OPERATION_ENABLED and self.mode == MODE_PROFILE_TORQUE:
                if abs(self.torque_actual_permille() - self._effective_target_permille()) <= self.target_window_permille:
                    word |= 0x0400  # target reached
                if abs(self.target_torque_permille) > self.max_torque_permille:
                    word |= 0x0800  # internal limit active
            return word

    # -- writes ----------------------------------------------------------------------------------------

    def write_controlword(self, cw: int) -> None:
        with self.lock:
            cw &= 0xFFFF
            rising_reset = bool(cw & 0x80) and not (self.controlword & 0x80)
            rising_set_point = bool(cw & CW_NEW_SET_POINT) and not (self.controlword & CW_NEW_SET_POINT)
            self.controlword = cw
            state = self.state
            if state in (State.FAULT, State.FAULT_REACTION_ACTIVE):
                if state is State.FAULT and rising_reset:
                    self.error_code = 0
                    self.error_register = 0
                    self._set_state(State.SWITCH_ON_DISABLED)
                    self._emcy(0x0000, 0)  # error reset
                return
            if cw & 0x80:
                return  # bit 7 set: fault reset command, no other transition
            if not cw & 0x02:
                command = "disable voltage"
            elif not cw & 0x04:
                command = "quick stop"
            elif not cw & 0x01:
                command = "shutdown"
            elif not cw & 0x08:
                command = "switch on"
            else:
                command = "enable operation"
            S = State
            nxt = {
                (S.SWITCH_ON_DISABLED, "shutdown"): S.READY_TO_SWITCH_ON,
                (S.READY_TO_SWITCH_ON, "switch on"): S.SWITCHED_ON,
                (S.READY_TO_SWITCH_ON, "enable operation"): S.OPERATION_ENABLED,
                (S.READY_TO_SWITCH_ON, "disable voltage"): S.SWITCH_ON_DISABLED,
                (S.READY_TO_SWITCH_ON, "quick stop"): S.SWITCH_ON_DISABLED,
                (S.SWITCHED_ON, "enable operation"): S.OPERATION_ENABLED,
                (S.SWITCHED_ON, "shutdown"): S.READY_TO_SWITCH_ON,
                (S.SWITCHED_ON, "disable voltage"): S.SWITCH_ON_DISABLED,
                (S.SWITCHED_ON, "quick stop"): S.SWITCH_ON_DISABLED,
                (S.OPERATION_ENABLED, "switch on"): S.SWITCHED_ON,
                (S.OPERATION_ENABLED, "shutdown"): S.READY_TO_SWITCH_ON,
                (S.OPERATION_ENABLED, "disable voltage"): S.SWITCH_ON_DISABLED,
                (S.OPERATION_ENABLED, "quick stop"): S.QUICK_STOP_ACTIVE,
                (S.QUICK_STOP_ACTIVE, "disable voltage"): S.SWITCH_ON_DISABLED,
            }.get((state, command))
            if state is S.QUICK_STOP_ACTIVE and command == "enable operation" and 5 <= self.quick_stop_option <= 8:
                nxt = S.OPERATION_ENABLED
            if nxt is not None:
                self._set_state(nxt)
            elif (rising_set_point and state is S.OPERATION_ENABLED and command == "enable operation"
                  and self.mode == MODE_PROFILE_POSITION):
                self._start_move()

    def _start_move(self) -> None:
        """A new set-point in profile position: turn the output to 0x607A at 0x6081 (no torque applied)."""
        velocity = self.profile_velocity_counts_per_s / self.counts_per_rev * 360.0
        self.physics.move_output(self.target_position_counts / self.counts_per_rev * 360.0, max(velocity, 1e-6))

    def write_mode(self, mode: int) -> None:
        with self.lock:
            mode = to_int16(mode) if mode > 127 else mode
            if mode != 0 and not (mode in range(1, 32) and self.supported_modes & (1 << (mode - 1))):
                raise DriveCommandError(f"mode {mode} not supported (0x6502 = 0x{self.supported_modes:04X})")
            self.mode = mode
            self._apply()

    def write_target_torque(self, permille: int) -> None:
        with self.lock:
            self.target_torque_permille = to_int16(permille)
            self._apply()

    def write_target_position(self, counts: int) -> None:
        with self.lock:
            counts = int(counts)
            counts = counts - (1 << 32) if counts >= (1 << 31) else counts  # INT32 carried as unsigned
            self.target_position_counts = counts

    def write_profile_velocity(self, counts_per_s: int) -> None:
        with self.lock:
            if not 0 < counts_per_s <= 0xFFFFFFFF:
                raise DriveCommandError(f"profile velocity {counts_per_s} counts/s out of range (must be > 0)")
            self.profile_velocity_counts_per_s = int(counts_per_s)

    def write_max_torque(self, permille: int) -> None:
        with self.lock:
            if not 0 <= permille <= 0xFFFF:
                raise DriveCommandError(f"max torque {permille} ‰ out of range")
            self.max_torque_permille = int(permille)
            self._apply()

    def write_torque_slope(self, permille_per_s: int) -> None:
        with self.lock:
            if not 0 < permille_per_s <= 0xFFFFFFFF:
                raise DriveCommandError(f"torque slope {permille_per_s} ‰/s out of range (must be > 0)")
            self.torque_slope_permille_per_s = int(permille_per_s)
            self._apply()

    def write_rated_torque(self, mnm: int) -> None:
        with self.lock:
            if self.state is State.OPERATION_ENABLED:
                raise DriveCommandError("rated torque cannot change in OPERATION ENABLED", kind="state")
            if not 0 < mnm <= 0xFFFFFFFF:
                raise DriveCommandError(f"rated torque {mnm} mN·m out of range")
            self.rated_torque_mnm = int(mnm)

    def write_comm_timeout(self, timeout_ms: int) -> None:
        with self.lock:
            if not 0 <= timeout_ms <= 0xFFFF:
                raise DriveCommandError(f"communication timeout {timeout_ms} ms out of range (0 = off … 65535)")
            self.comm_timeout_ms = int(timeout_ms)

    def write_abort_connection_option(self, option: int) -> None:
        with self.lock:
            option = to_int16(option)
            if option not in ABORT_CONNECTION_OPTIONS:
                raise DriveCommandError(f"abort connection option {option} not supported (0, 1, 2, 3)")
            self.abort_connection_option = option

    def write_quick_stop_option(self, option: int) -> None:
        with self.lock:
            option = to_int16(option)
            if option not in (0, 1, 2, 5, 6):
                raise DriveCommandError(f"quick stop option {option} not supported (0, 1, 2, 5, 6)")
            self.quick_stop_option = option

    # -- what the front ends see ------------------------------------------------------------------------

    def od_getters(self) -> dict[int, Callable[[], int]]:
        """Object index -> its present value (SDO uploads of the live objects)."""
        return {
            0x6041: self.statusword, 0x6061: self.mode_display, 0x6077: self.torque_actual_permille,
            0x6064: self.position_counts, 0x603F: lambda: self.error_code, 0x1001: lambda: self.error_register,
            0x6040: lambda: self.controlword, 0x6060: lambda: self.mode,
            0x6071: lambda: self.target_torque_permille, 0x6072: lambda: self.max_torque_permille,
            0x6087: lambda: self.torque_slope_permille_per_s, 0x6076: lambda: self.rated_torque_mnm,
            0x605A: lambda: self.quick_stop_option, 0x607A: lambda: self.target_position_counts,
            0x6081: lambda: self.profile_velocity_counts_per_s,
        }

    def od_setters(self) -> dict[int, Callable[[int], None]]:
        """Object index -> what an SDO download of it does."""
        return {
            0x6040: self.write_controlword, 0x6060: self.write_mode, 0x6071: self.write_target_torque,
            0x6072: self.write_max_torque, 0x6087: self.write_torque_slope, 0x6076: self.write_rated_torque,
            0x605A: self.write_quick_stop_option, 0x607A: self.write_target_position,
            0x6081: self.write_profile_velocity,
        }

    def register_getters(self) -> dict[str, Callable[[], int]]:
        """Register-map name -> its present value (Modbus reads)."""
        return {
            "controlword": lambda: self.controlword, "statusword": self.statusword,
            "error_code": lambda: self.error_code, "error_register": lambda: self.error_register,
            "mode": lambda: self.mode, "mode_display": self.mode_display, "position_actual": self.position_counts,
            "target_torque": lambda: self.target_torque_permille, "max_torque": lambda: self.max_torque_permille,
            "torque_actual": self.torque_actual_permille, "torque_slope": lambda: self.torque_slope_permille_per_s,
            "rated_torque": lambda: self.rated_torque_mnm, "quick_stop_option": lambda: self.quick_stop_option,
            "comm_timeout": lambda: self.comm_timeout_ms,
            "abort_connection_option": lambda: self.abort_connection_option,
            "target_position": lambda: self.target_position_counts,
            "profile_velocity": lambda: self.profile_velocity_counts_per_s,
        }

    def register_setters(self) -> dict[str, Callable[[int], None]]:
        """Register-map name -> what a Modbus write of it does."""
        return {
            "controlword": self.write_controlword, "mode": self.write_mode,
            "target_torque": self.write_target_torque, "max_torque": self.write_max_torque,
            "torque_slope": self.write_torque_slope, "rated_torque": self.write_rated_torque,
            "quick_stop_option": self.write_quick_stop_option, "comm_timeout": self.write_comm_timeout,
            "abort_connection_option": self.write_abort_connection_option,
            "target_position": self.write_target_position, "profile_velocity": self.write_profile_velocity,
        }

    def write_rpdo(self, controlword: int, target: int) -> None:
        """RPDO1: the target (torque ‰), then the controlword."""
        with self.lock:
            self.write_target_torque(target)
            self.write_controlword(controlword)

    def process_values(self) -> dict[int, int]:
        """The values of the objects the TPDOs carry, taken together (one snapshot)."""
        with self.lock:
            return {0x6041: self.statusword(), 0x6077: self.torque_actual_permille(), 0x6064: self.position_counts(),
                    0x6061: self.mode_display(), 0x603F: self.error_code}

    # -- faults ----------------------------------------------------------------------------------------

    def inject_fault(self, code: int, register: int | None = None) -> None:
        """Drive fault (e.g. 0x2310 over-current): FAULT REACTION ACTIVE → FAULT, torque off, EMCY sent."""
        with self.lock:
            if register is None:
                register = 0x01 | ERROR_REGISTER_FOR.get((code >> 12) & 0xF, 0)
            self.error_code = code & 0xFFFF
            self.error_register = register & 0xFF
            self._set_state(State.FAULT_REACTION_ACTIVE)
            self._set_state(State.FAULT)
            self._emcy(self.error_code, self.error_register)

    def communication_lost(self) -> str | None:
        """The master's heartbeat or requests stopped: if the drive is powering the load, the reaction of the
        abort connection option code (0x6007); returns what it did (None: nothing)."""
        with self.lock:
            if self.state not in (State.OPERATION_ENABLED, State.QUICK_STOP_ACTIVE):
                return None
            option = self.abort_connection_option
            if option == ABORT_CONNECTION_FAULT:
                self.inject_fault(EMCY_COMMUNICATION)
                return "fault 0x8130"
            if option == ABORT_CONNECTION_DISABLE_VOLTAGE:
                self.target_torque_permille = 0
                self._set_state(State.SWITCH_ON_DISABLED)
                return "disable voltage"
            if option == ABORT_CONNECTION_QUICK_STOP:
                self.target_torque_permille = 0
                if self.state is State.OPERATION_ENABLED:
                    self._set_state(State.QUICK_STOP_ACTIVE)
                return "quick stop"
            return None

    # -- internals -------------------------------------------------------------------------------------

    def _emcy(self, code: int, register: int) -> None:
        for listener in list(self._emcy_listeners):
            listener(code, register)

    def _set_state(self, state: State) -> None:
        self.state = state
        self._apply()

    def _apply(self) -> None:
        """Push the drive's present command to the physics."""
        rated = self.rated_torque_nm
        if not (self.state is State.OPERATION_ENABLED and self.mode == MODE_PROFILE_POSITION):
            self.physics.stop_output()  # a move ends where the output is when the drive leaves position mode
        if self.state is State.OPERATION_ENABLED and self.mode == MODE_PROFILE_POSITION:
            # the output is held and turned by position control: no torque through the reducer in this model
            self.physics.set_drive_enabled(True)
            self.physics.set_torque_target(0.0, self.torque_slope_permille_per_s / 1000.0 * rated)
        elif self.state is State.OPERATION_ENABLED and self.mode == MODE_PROFILE_TORQUE:
            self.physics.set_drive_enabled(True)
            self.physics.set_torque_target(
                self._effective_target_permille() / 1000.0 * rated,
                self.torque_slope_permille_per_s / 1000.0 * rated,
            )
        elif self.state is State.OPERATION_ENABLED:
            # enabled without a torque mode: hold zero torque
            self.physics.set_drive_enabled(True)
            self.physics.set_torque_target(0.0, self.torque_slope_permille_per_s / 1000.0 * rated)
        elif self.state is State.QUICK_STOP_ACTIVE and self.quick_stop_option != 0:
            self.physics.set_drive_enabled(True)
            self.physics.set_torque_target(0.0, self.quick_stop_slope_permille_per_s / 1000.0 * rated)
        else:
            if self.state is State.QUICK_STOP_ACTIVE:  # option 0: disable drive at once
                self.state = State.SWITCH_ON_DISABLED
            self.physics.set_torque_target(0.0, self.quick_stop_slope_permille_per_s / 1000.0 * rated)
            self.physics.set_drive_enabled(False)

    def _on_tick(self, reading: PhysicsReading) -> None:
        # called by SharedPhysics after every advance, with the lock held
        self._latest = reading
        if self.state is State.QUICK_STOP_ACTIVE and self.quick_stop_option in (1, 2):
            if abs(reading.applied_torque_nm) <= self.target_window_permille / 1000.0 * self.rated_torque_nm:
                self._set_state(State.SWITCH_ON_DISABLED)


class VelocityDrive402Model(Drive402Model):
    """The second axis's input drive: the same state machine and communication watchdog, in profile velocity (mode 3,
    0x6502 = 0x0004). In OPERATION ENABLED the velocity ramps toward the target 0x60FF with the profile acceleration
    0x6083 (speeding up) or deceleration 0x6084 (slowing down), limited by 0x607F; quick stop ramps to 0 with 0x6085 and
    (option 1/2) ends in SWITCH ON DISABLED; any other state (disabled, fault) stops the shaft at once (the brake).
    Every physics tick hands the velocity and the loader's torque to the drivetrain (``sim.instruments.drivetrain``),
    which gives position actual 0x6064 (the input shaft) and torque actual 0x6077 (the input torque). Velocities and
    ramps in counts/s (/s²) of ``counts_per_rev`` per input revolution. Statusword bit 10: |actual − target| within
    ``velocity_window_counts``."""

    supported_modes = SUPPORTED_MODES_VELOCITY

    def __init__(self, physics: SharedPhysics, drivetrain: DriveTrainPhysics, *, counts_per_rev: int = 1 << 20,
                 velocity_window_counts: int | None = None, **options: int):
        self.drivetrain = drivetrain
        self.velocity_window_counts = (max(1, counts_per_rev // 3600) if velocity_window_counts is None
                                       else int(velocity_window_counts))  # 0.1 deg/s
        self._velocity = 0.0  # counts/s, the ramp's state
        self._last_tick_s: float | None = None
        super().__init__(physics, counts_per_rev=counts_per_rev, **options)

    def _init_physics(self) -> None:
        """The input drive leaves the loader alone."""

    def _power_on_state(self) -> None:
        super()._power_on_state()
        self.target_velocity_counts = 0
        self.max_profile_velocity_counts = 0x7FFFFFFF
        self.profile_acceleration_counts = max(1, self.counts_per_rev * 10)  # 3600 deg/s²
        self.profile_deceleration_counts = self.profile_acceleration_counts
        self.quick_stop_deceleration_counts = self.profile_acceleration_counts * 10
        self._velocity = 0.0

    # -- values ----------------------------------------------------------------------------------------

    def velocity_counts(self) -> int:
        with self.lock:
            return max(-(1 << 31), min((1 << 31) - 1, round(self._velocity)))

    def velocity_deg_per_s(self) -> float:
        with self.lock:
            return self._velocity / self.counts_per_rev * 360.0

    def torque_actual_permille(self) -> int:
        with self.lock:
            value = round(self.drivetrain.input_torque_nm(self._latest.time_s) / self.rated_torque_nm * 1000.0)
            return max(-32768, min(32767, value))

    def position_counts(self) -> int:
        with self.lock:
            value = round(self.drivetrain.input_angle_deg(self._latest.time_s) / 360.0 * self.counts_per_rev)
            return (value + (1 << 31)) % (1 << 32) - (1 << 31)  # INT32 wraps like a real drive's counter

    def statusword(self) -> int:
        with self.lock:
            word = self.state.value | 0x0200
            if self.state is State.OPERATION_ENABLED and self.mode == MODE_PROFILE_VELOCITY:
                if abs(self._velocity - self._effective_target()) <= self.velocity_window_counts:
                    word |= SW_TARGET_REACHED
                if abs(self.target_velocity_counts) > self.max_profile_velocity_counts:
                    word |= 0x0800  # internal limit active
            return word

    def _effective_target(self) -> float:
        if self.state is State.OPERATION_ENABLED and self.mode == MODE_PROFILE_VELOCITY:
            limit = self.max_profile_velocity_counts
            return float(max(-limit, min(limit, self.target_velocity_counts)))
        return 0.0

    # -- writes ----------------------------------------------------------------------------------------

    def write_target_velocity(self, counts_per_s: int) -> None:
        with self.lock:
            counts_per_s = int(counts_per_s)
            self.target_velocity_counts = counts_per_s - (1 << 32) if counts_per_s >= (1 << 31) else counts_per_s

    def _write_unsigned(self, name: str, value: int) -> None:
        with self.lock:
            if not 0 < value <= 0xFFFFFFFF:
                raise DriveCommandError(f"{name} {value} out of range (must be > 0)")
            setattr(self, f"{name}_counts", int(value))

    def _unsigned_setter(self, name: str) -> Callable[[int], None]:
        """The write of one of the ramps or the speed limit (counts/s or counts/s², > 0)."""
        return functools.partial(self._write_unsigned, name)

    def write_rpdo(self, controlword: int, target: int) -> None:
        """RPDO1: the target velocity, then the controlword."""
        with self.lock:
            self.write_target_velocity(target & 0xFFFFFFFF)
            self.write_controlword(controlword)

    def process_values(self) -> dict[int, int]:
        with self.lock:
            return {0x6041: self.statusword(), 0x606C: self.velocity_counts(), 0x6064: self.position_counts(),
                    0x6061: self.mode_display(), 0x603F: self.error_code, 0x6077: self.torque_actual_permille()}

    def od_getters(self) -> dict[int, Callable[[], int]]:
        return {
            0x6041: self.statusword, 0x6061: self.mode_display, 0x6077: self.torque_actual_permille,
            0x6064: self.position_counts, 0x606C: self.velocity_counts, 0x603F: lambda: self.error_code,
            0x1001: lambda: self.error_register, 0x6040: lambda: self.controlword, 0x6060: lambda: self.mode,
            0x60FF: lambda: self.target_velocity_counts, 0x607F: lambda: self.max_profile_velocity_counts,
            0x6083: lambda: self.profile_acceleration_counts, 0x6084: lambda: self.profile_deceleration_counts,
            0x6085: lambda: self.quick_stop_deceleration_counts, 0x6076: lambda: self.rated_torque_mnm,
            0x605A: lambda: self.quick_stop_option,
        }

    def od_setters(self) -> dict[int, Callable[[int], None]]:
        return {
            0x6040: self.write_controlword, 0x6060: self.write_mode, 0x60FF: self.write_target_velocity,
            0x607F: self._unsigned_setter("max_profile_velocity"),
            0x6083: self._unsigned_setter("profile_acceleration"),
            0x6084: self._unsigned_setter("profile_deceleration"),
            0x6085: self._unsigned_setter("quick_stop_deceleration"),
            0x6076: self.write_rated_torque, 0x605A: self.write_quick_stop_option,
        }

    def register_getters(self) -> dict[str, Callable[[], int]]:
        return {
            "controlword": lambda: self.controlword, "statusword": self.statusword,
            "error_code": lambda: self.error_code, "error_register": lambda: self.error_register,
            "mode": lambda: self.mode, "mode_display": self.mode_display, "position_actual": self.position_counts,
            "velocity_actual": self.velocity_counts, "torque_actual": self.torque_actual_permille,
            "target_velocity": lambda: self.target_velocity_counts,
            "max_profile_velocity": lambda: self.max_profile_velocity_counts,
            "profile_acceleration": lambda: self.profile_acceleration_counts,
            "profile_deceleration": lambda: self.profile_deceleration_counts,
            "quick_stop_deceleration": lambda: self.quick_stop_deceleration_counts,
            "rated_torque": lambda: self.rated_torque_mnm, "quick_stop_option": lambda: self.quick_stop_option,
            "comm_timeout": lambda: self.comm_timeout_ms,
            "abort_connection_option": lambda: self.abort_connection_option,
        }

    def register_setters(self) -> dict[str, Callable[[int], None]]:
        return {
            "controlword": self.write_controlword, "mode": self.write_mode,
            "target_velocity": self.write_target_velocity,
            **{name: self._unsigned_setter(name) for name in ("max_profile_velocity", "profile_acceleration",
                                                               "profile_deceleration", "quick_stop_deceleration")},
            "rated_torque": self.write_rated_torque, "quick_stop_option": self.write_quick_stop_option,
            "comm_timeout": self.write_comm_timeout, "abort_connection_option": self.write_abort_connection_option,
        }

    # -- internals -------------------------------------------------------------------------------------

    def _apply(self) -> None:
        """Leaving the powered states stops the shaft at once (the brake); the ramps run on the ticks."""
        if self.state not in (State.OPERATION_ENABLED, State.QUICK_STOP_ACTIVE):
            self._velocity = 0.0
        elif self.state is State.QUICK_STOP_ACTIVE and self.quick_stop_option == 0:
            self.state = State.SWITCH_ON_DISABLED
            self._velocity = 0.0

    def _on_tick(self, reading: PhysicsReading) -> None:
        # called by SharedPhysics after every advance, with the lock held
        previous = self._last_tick_s
        self._last_tick_s = reading.time_s
        self._latest = reading
        dt = 0.0 if previous is None else max(0.0, reading.time_s - previous)
        target = self._effective_target()
        if self.state is State.QUICK_STOP_ACTIVE:
            rate = float(self.quick_stop_deceleration_counts)
        elif abs(target) > abs(self._velocity) and target * self._velocity >= 0:
            rate = float(self.profile_acceleration_counts)
        else:
            rate = float(self.profile_deceleration_counts)
        step = rate * dt
        if abs(target - self._velocity) <= step:
            self._velocity = target
        else:
            self._velocity += math.copysign(step, target - self._velocity)
        if self.state not in (State.OPERATION_ENABLED, State.QUICK_STOP_ACTIVE):
            self._velocity = 0.0
        self.drivetrain.command(reading.time_s, self._velocity / self.counts_per_rev * 360.0,
                                reading.applied_torque_nm)
        if (self.state is State.QUICK_STOP_ACTIVE and self.quick_stop_option in (1, 2)
                and abs(self._velocity) <= self.velocity_window_counts):
            self._velocity = 0.0
            self._set_state(State.SWITCH_ON_DISABLED)

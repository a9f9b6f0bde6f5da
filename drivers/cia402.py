"""CiA 402 drive semantics shared by the CANopen and Modbus loader drivers (protocols.md §3.1–3.2).

Statusword decoding, the controlword commands, torque scaling (‰ of the motor rated torque 0x6076) and the
validation of torque commands before any byte leaves.
"""

from __future__ import annotations

import math

from drivers.base import CommandRejected

MODE_PROFILE_TORQUE = 4

# controlword commands (bits 7,3,2,1,0)
CW_DISABLE_VOLTAGE = 0x0000
CW_QUICK_STOP = 0x000B  # quick stop with the enable bits kept (0x0002 works too)
CW_SHUTDOWN = 0x0006
CW_SWITCH_ON = 0x0007
CW_ENABLE_OPERATION = 0x000F
CW_FAULT_RESET = 0x0080

# (mask, value, name), most specific first
_STATES = (
    (0x4F, 0x00, "NOT READY TO SWITCH ON"),
    (0x4F, 0x40, "SWITCH ON DISABLED"),
    (0x6F, 0x21, "READY TO SWITCH ON"),
    (0x6F, 0x23, "SWITCHED ON"),
    (0x6F, 0x27, "OPERATION ENABLED"),
    (0x6F, 0x07, "QUICK STOP ACTIVE"),
    (0x4F, 0x0F, "FAULT REACTION ACTIVE"),
    (0x4F, 0x08, "FAULT"),
)

# statusword mask/value that each target state is recognised by
STATE_PATTERN = {name: (mask, value) for mask, value, name in _STATES}


def state_from_statusword(statusword: int) -> str:
    for mask, value, name in _STATES:
        if statusword & mask == value:
            return name
    return f"UNKNOWN (0x{statusword:04X})"


def is_fault(statusword: int) -> bool:
    return bool(statusword & 0x08)


def to_int16(value: int) -> int:
    value &= 0xFFFF
    return value - 0x10000 if value & 0x8000 else value


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

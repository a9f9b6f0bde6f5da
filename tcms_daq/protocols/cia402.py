"""CiA 402 drive profile words shared by the loader drivers and the simulated drive: the controlword commands,
the statusword state patterns, profile-torque mode, and the drive's EDS (object dictionary) file."""

from __future__ import annotations

from importlib import resources
from pathlib import Path

MODE_PROFILE_POSITION = 1  # moves of the output between the positions of a multi-position test
MODE_PROFILE_TORQUE = 4
SUPPORTED_MODES = 0x0009  # 0x6502: bit 0 profile position, bit 3 profile torque

CW_NEW_SET_POINT = 0x0010  # controlword bit 4 (profile position): a rising edge starts the move to 0x607A
SW_TARGET_REACHED = 0x0400  # statusword bit 10
SW_SET_POINT_ACK = 0x1000  # statusword bit 12 (profile position): the new set-point was taken

# controlword commands (bits 7,3,2,1,0)
CW_DISABLE_VOLTAGE = 0x0000
CW_QUICK_STOP = 0x000B  # quick stop with the enable bits kept (0x0002 works too)
CW_SHUTDOWN = 0x0006
CW_SWITCH_ON = 0x0007
CW_ENABLE_OPERATION = 0x000F
CW_FAULT_RESET = 0x0080

EMCY_COMMUNICATION = 0x8130  # heartbeat / life guard error

# (mask, value, name), most specific first
STATES = (
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
STATE_PATTERN = {name: (mask, value) for mask, value, name in STATES}


def state_from_statusword(statusword: int) -> str:
    for mask, value, name in STATES:
        if statusword & mask == value:
            return name
    return f"UNKNOWN (0x{statusword:04X})"


def is_fault(statusword: int) -> bool:
    return bool(statusword & 0x08)


def to_int16(value: int) -> int:
    """A 16-bit register/object value as a signed integer."""
    value &= 0xFFFF
    return value - 0x10000 if value & 0x8000 else value


def drive_eds_path() -> Path:
    """The EDS of the (simulated and the example real) CiA 402 drive, shipped as package data."""
    return Path(str(resources.files(__package__).joinpath("drive402.eds")))

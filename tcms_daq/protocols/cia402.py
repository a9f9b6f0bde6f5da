"""CiA 402 drive profile words shared by the loader drivers and the simulated drive: the controlword commands,
the statusword state patterns, profile-torque mode, and the drive's EDS (object dictionary) file."""

from __future__ import annotations

from importlib import resources
from pathlib import Path

MODE_PROFILE_POSITION = 1  # moves of the output between the positions of a multi-position test
MODE_PROFILE_VELOCITY = 3  # the input drive of the second axis: target velocity 0x60FF, velocity actual 0x606C
MODE_PROFILE_TORQUE = 4
SUPPORTED_MODES = 0x0009  # 0x6502: bit 0 profile position, bit 3 profile torque
SUPPORTED_MODES_VELOCITY = 0x0004  # 0x6502 of the input drive: bit 2 profile velocity

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

# The drive's own communication watchdog (a dead master or a silent link stops the drive by itself).
# 0x6007 abort connection option code (CiA 402): what the drive does when its connection to the master is lost
# (heartbeat / node guarding on CANopen, the communication timeout on Modbus)
ABORT_CONNECTION_NO_ACTION = 0
ABORT_CONNECTION_FAULT = 1  # fault 0x8130: the fault reaction takes the torque off, the drive ends in FAULT
ABORT_CONNECTION_DISABLE_VOLTAGE = 2
ABORT_CONNECTION_QUICK_STOP = 3  # quick stop ramp, then (0x605A = 1/2) SWITCH ON DISABLED
ABORT_CONNECTION_OPTIONS = (ABORT_CONNECTION_NO_ACTION, ABORT_CONNECTION_FAULT, ABORT_CONNECTION_DISABLE_VOLTAGE,
                            ABORT_CONNECTION_QUICK_STOP)
# CANopen: the drive's heartbeat consumer (0x1016) waits this many periods of the master's heartbeat producer, so
# a master thread held up by a loaded machine for a few periods is not taken for a dead master
HEARTBEAT_CONSUMER_PERIODS = 10
MIN_HEARTBEAT_CONSUMER_PERIODS = 3
MAX_DEFAULT_CONSUMER_TIMEOUT_MS = 1000


def heartbeat_consumer_timeout_ms(master_heartbeat_ms: int) -> int:
    """The drive's heartbeat consumer time (ms) for a master producing every ``master_heartbeat_ms``: ten periods,
    at most 1 s of silence (and never fewer than three periods)."""
    return max(MIN_HEARTBEAT_CONSUMER_PERIODS * master_heartbeat_ms,
               min(HEARTBEAT_CONSUMER_PERIODS * master_heartbeat_ms, MAX_DEFAULT_CONSUMER_TIMEOUT_MS))

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

# the states in which a drive can apply torque
POWERED_STATES = frozenset({"OPERATION ENABLED", "SWITCHED ON", "QUICK STOP ACTIVE"})

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


def velocity_drive_eds_path() -> Path:
    """The EDS of the (simulated) input drive in profile velocity (mode 3), shipped as package data."""
    return Path(str(resources.files(__package__).joinpath("drive402-velocity.eds")))

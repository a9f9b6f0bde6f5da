"""The options of each hardware driver: the keys of its ``[instruments.<kind>]`` table as a pydantic model (the
driver class names it as ``options_model``). The bench config validates them once, when it is read
(``tcms_daq.config.drivers``); a driver is built from its model and re-checks nothing. Defaults here are the
drivers' defaults; docs/hardware.md's option tables are held to these models by
``tests/drivers/test_drivers_options.py``.

Units are in the names (``_s``, ``_ms``, ``_nm``, ``_nm_per_s``). What a bench does not configure — the clock
readings are stamped with, the timebase a driver waits on, a test's packet tracer — is passed to the constructor
beside the options.
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from pydantic import Field, model_validator

from tcms_daq.config.models import DEFAULT_COMM_TIMEOUT_MS, DriverOptions
from tcms_daq.protocols.aed import MAX_NOV
from tcms_daq.protocols.cia402 import MIN_HEARTBEAT_CONSUMER_PERIODS, heartbeat_consumer_timeout_ms


class SerialOptions(DriverOptions):
    """A polled instrument on a serial line (``/dev/ttyUSB0``, ``COM3``, ``socket://host:port``, ``rfc2217://…``)."""

    name: str = Field("serial instrument", min_length=1, description="the instrument's name in messages")
    baudrate: int = Field(9600, gt=0, description="the line speed (Bd)")
    timeout_s: float = Field(0.5, gt=0.0, description="the longest wait for one reply (s)")
    reconnect_attempts: int = Field(3, ge=0, description="re-opens of the port before Disconnected")
    reconnect_delay_s: float = Field(0.2, ge=0.0, description="pause before each re-open (s)")


class ND287Options(SerialOptions):
    """[instruments.angle] of ``driver = "nd287"``: HEIDENHAIN ND 287 (7E2)."""

    name: str = Field("ND 287", min_length=1, description="the instrument's name in messages")
    baudrate: int = Field(9600, gt=0, description="the ND 287's interface setting (Bd)")
    readings_per_read: int = Field(1, ge=1, description="polled readings per read()")


class AEDOptions(SerialOptions):
    """[instruments.torque] of ``driver = "aed"``: HBM AED-style amplifier (8E1)."""

    name: str = Field("AED", min_length=1, description="the instrument's name in messages")
    baudrate: int = Field(9600, gt=0, description="the amplifier's BDR (Bd)")
    nominal_torque_nm: float = Field(2000.0, gt=0.0, description="the transducer's nominal torque (N·m)")
    nominal_output: int = Field(0, ge=0, le=MAX_NOV, strict=True,
                                description="NOV: the reading at nominal torque (0: the factory 1 000 000)")


class CiA402Options(DriverOptions):
    """What both CiA 402 loaders take: limits, the default slope, state-change deadlines, the position scaling."""

    name: str = Field("CiA 402 drive", min_length=1, description="the instrument's name in messages")
    max_torque_nm: float | None = Field(None, gt=0.0, description="never command more (N·m; 0x6072 on enable)")
    torque_slope_nm_per_s: float = Field(200.0, gt=0.0, description="default slope 0x6087 (N·m/s)")
    state_timeout_s: float = Field(2.0, gt=0.0, description="the longest wait for a state change (s)")
    counts_per_rev: int = Field(1 << 20, gt=0, strict=True,
                                description="position actual 0x6064 per output revolution")
    move_torque_window_nm: float | None = Field(
        None, gt=0.0, description="|torque| at which a move may start (N·m; default the drive's own)")


class CanopenLinkOptions(DriverOptions):
    """The CANopen link of a CiA 402 drive (what both CANopen drivers take). The URL is
    ``socketcand://host:port/channel``, ``virtual://channel`` or a python-can adapter ``<interface>://<channel>``
    (with ``bitrate``)."""

    name: str = Field("CiA 402 drive", min_length=1, description="the instrument's name in messages")

    node_id: int = Field(1, ge=1, le=127, description="the drive's node id")
    master_node_id: int = Field(0x7F, ge=1, le=127, description="this master's node id (its heartbeat's)")
    eds: Path | None = Field(None, description="the drive's EDS/DCF (default: the packaged drive402.eds)")
    bitrate: int | None = Field(None, gt=0, description="the bus's bitrate (adapters only)")
    sdo_timeout_s: float = Field(1.0, gt=0.0, description="the longest wait for an SDO answer (s)")
    heartbeat_ms: int = Field(100, gt=0, description="the drive's heartbeat period 0x1017 (ms)")
    heartbeat_timeout_s: float | None = Field(
        None, gt=0.0, description="no heartbeat this long: the link is lost (s; default 3.5 periods, ≥ 0.2 s)")
    master_heartbeat_ms: int = Field(100, ge=10, le=1000, strict=True,
                                     description="this master's heartbeat period (ms)")
    drive_consumer_timeout_ms: int | None = Field(
        None, ge=0, le=65535, strict=True,
        description="the drive faults (0x8130) after this much silence of the master (ms; default ten periods, "
                    "at most 1 s; 0 off)")
    connect_timeout_s: float = Field(2.0, gt=0.0, description="the longest wait for the drive at connect (s)")
    reconnect_attempts: int = Field(2, ge=1, description="re-opens of a lost link before Disconnected")
    reconnect_timeout_s: float | None = Field(
        None, gt=0.0, description="one re-open's wait for the heartbeat (s; default connect_timeout_s)")

    @model_validator(mode="after")
    def _check(self) -> CanopenLinkOptions:
        if self.node_id == self.master_node_id:
            raise ValueError(f"node ids must differ (drive {self.node_id}, master {self.master_node_id})")
        consumer = self.consumer_timeout_ms
        if consumer and consumer < MIN_HEARTBEAT_CONSUMER_PERIODS * self.master_heartbeat_ms:
            raise ValueError(f"drive_consumer_timeout_ms {consumer} must be at least {MIN_HEARTBEAT_CONSUMER_PERIODS}"
                             f" master heartbeat periods ({self.master_heartbeat_ms} ms)")
        return self

    @property
    def consumer_timeout_ms(self) -> int:
        """The drive's heartbeat consumer time (ms; 0 off): as configured, else derived from this master's period
        with margin (a loaded host may hold the producer thread up for a few periods)."""
        if self.drive_consumer_timeout_ms is not None:
            return self.drive_consumer_timeout_ms
        return heartbeat_consumer_timeout_ms(self.master_heartbeat_ms)

    @property
    def link_timeout_s(self) -> float:
        """How long without the drive's heartbeat the link counts as lost (s)."""
        return self.heartbeat_timeout_s or max(3.5 * self.heartbeat_ms / 1000.0, 0.2)


class CiA402CanopenOptions(CiA402Options, CanopenLinkOptions):
    """[instruments.loader] of ``driver = "cia402-canopen"``: a CiA 402 drive over CANopen. The URL is
    ``socketcand://host:port/channel``, ``virtual://channel`` or a python-can adapter ``<interface>://<channel>``
    (with ``bitrate``)."""

    name: str = Field("CiA 402 drive (CANopen)", min_length=1, description="the instrument's name in messages")


class ModbusLinkOptions(DriverOptions):
    """The Modbus link of a CiA 402 drive (what both Modbus drivers take): TCP (``tcp://host:port``) or RTU (a serial
    port or ``socket://host:port``), and the drive's own communication watchdog the driver arms on connect."""

    name: str = Field("CiA 402 drive", min_length=1, description="the instrument's name in messages")

    register_map: Path | None = Field(None, description="the drive's register map TOML (default: the packaged "
                                                       "modbus-drive.toml)")
    device_id: int | None = Field(None, ge=0, le=247, description="the drive's Modbus address (default: the map's)")
    timeout_s: float = Field(0.5, gt=0.0, description="the longest wait for one reply (s)")
    retries: int = Field(0, ge=0, description="pymodbus retries of one request")
    baudrate: int = Field(115200, gt=0, description="RTU line speed (Bd)")
    reconnect_attempts: int = Field(3, ge=0, description="re-opens of the link before Disconnected")
    reconnect_delay_s: float = Field(0.2, ge=0.0, description="pause before each re-open (s)")
    serial_line: bool = Field(False, description="RTU through the driver's serial-line client (reads by length)")
    comm_timeout_ms: int = Field(DEFAULT_COMM_TIMEOUT_MS, ge=0, le=65535, strict=True,
                                 description="the drive reacts after this much silence (ms; 0 = off)")
    abort_connection_option: Literal[1, 2, 3] = Field(
        1, description="the drive's reaction (0x6007): 1 fault, 2 disable voltage, 3 quick stop")


class CiA402ModbusOptions(CiA402Options, ModbusLinkOptions):
    """[instruments.loader] of ``driver = "cia402-modbus"``: a CiA 402 drive over Modbus TCP (``tcp://host:port``)
    or RTU (a serial port or ``socket://host:port``)."""

    name: str = Field("CiA 402 drive (Modbus)", min_length=1, description="the instrument's name in messages")


class VelocityDriveOptions(DriverOptions):
    """What both input drives take (CiA 402 profile velocity, mode 3): the speed limit, the ramps, the state-change
    deadline, the input shaft's position scaling. Velocities at the input shaft (deg/s; 360 deg/s = 60 rpm);
    on the wire counts/s of ``counts_per_rev`` (0x60FF target velocity, 0x606C velocity actual)."""

    name: str = Field("input drive", min_length=1, description="the instrument's name in messages")
    max_velocity_deg_per_s: float = Field(3600.0, gt=0.0, description=(
        "never command more (deg/s at the input; 0x607F max profile velocity on enable)"))
    acceleration_deg_per_s2: float = Field(3600.0, gt=0.0, description=(
        "profile acceleration and deceleration 0x6083/0x6084 (deg/s²)"))
    quick_stop_deceleration_deg_per_s2: float = Field(36000.0, gt=0.0, description=(
        "quick-stop deceleration 0x6085 (deg/s²): the stop of a quick stop or a lost link"))
    velocity_window_deg_per_s: float = Field(1.0, gt=0.0, description="|velocity| below which the shaft is at rest")
    state_timeout_s: float = Field(2.0, gt=0.0, description="the longest wait for a state change (s)")
    counts_per_rev: int = Field(1 << 20, gt=0, strict=True,
                                description="position actual 0x6064 per input revolution (velocity in counts/s)")


class CiA402VelocityCanopenOptions(VelocityDriveOptions, CanopenLinkOptions):
    """[instruments.input_drive] of ``driver = "cia402-velocity-canopen"``: the input drive on the loader's CANopen
    bus at its own node id. Its master heartbeat comes from its own link (node id 0x7E by default, the loader's is
    0x7F), so the drive stops when the software behind its own link goes silent."""

    name: str = Field("input drive (CANopen)", min_length=1, description="the instrument's name in messages")
    node_id: int = Field(2, ge=1, le=127, description="the drive's node id")
    master_node_id: int = Field(0x7E, ge=1, le=127, description="this link's heartbeat node id")
    eds: Path | None = Field(None, description="the drive's EDS/DCF (default: the packaged drive402-velocity.eds)")


class CiA402VelocityModbusOptions(VelocityDriveOptions, ModbusLinkOptions):
    """[instruments.input_drive] of ``driver = "cia402-velocity-modbus"``: the input drive over Modbus TCP or RTU at
    its own unit id (the packaged map's ``device_id = 2``: on the loader's RS-485 line or behind its gateway)."""

    name: str = Field("input drive (Modbus)", min_length=1, description="the instrument's name in messages")
    register_map: Path | None = Field(None, description="the drive's register map TOML (default: the packaged "
                                                       "modbus-input-drive.toml)")


class ND287CoupledOptions(ND287Options):
    """[instruments.input_angle] of ``driver = "nd287-coupled"``: the ND 287 in its coupled-axes mode, X1 (the output
    encoder) and X2 (the input encoder) coupled as X1 − k·X2 on the display. ``ratio`` is the mounted reducer's: the
    display's factor k = 1/ratio is set on the display (its X2 scaling factor), not over RS-232; the driver checks
    that every frame is a coupled one (series ``S``)."""

    name: str = Field("ND 287 (X1 − k·X2)", min_length=1, description="the instrument's name in messages")
    ratio: float = Field(gt=0.0, description="the reducer's ratio i the display's k = 1/i was set for")


class CounterOptions(SerialOptions):
    """[instruments.input_angle] of ``driver = "counter-2axis"``: the two-axis counter interface (protocol
    ``tcms_daq.protocols.counter``: both encoders latched as one pair at ``rate_hz``). Axis 1 is the output encoder,
    axis 2 the input encoder; their counts per revolution must match what the card reports (CONF?)."""

    name: str = Field("two-axis counter", min_length=1, description="the instrument's name in messages")
    baudrate: int = Field(115200, gt=0, description="the line speed (Bd; ignored on TCP)")
    rate_hz: int = Field(1000, ge=1, le=20_000, description="latch rate of the card's timer (Hz)")
    counts_per_rev_output: int = Field(18_000 * 4096, gt=0, strict=True,
                                       description="axis 1 (output encoder) counts per revolution")
    counts_per_rev_input: int = Field(1 << 23, gt=0, strict=True,
                                      description="axis 2 (input encoder) counts per revolution")

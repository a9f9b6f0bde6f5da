"""CiA 402 servo loader over CANopen (canopen 2.4.1 on python-can 4.6.1): Loader.

URL: ``socketcand://host:port/channel`` (a socketcand daemon, e.g. the simulator's loopback hub) or
``virtual://channel`` (python-can's in-process virtual bus, tests). Other python-can interfaces:
``<interface>://<channel>`` (e.g. ``pcan://PCAN_USBBUS1``, ``socketcan://can0``) with ``bitrate`` given.

Sequence (CiA 301/402): wait for the drive's heartbeat → NMT pre-operational → SDO: check 0x1000 is a CiA 402
device, read the rated torque 0x6076, set the producer heartbeat 0x1017 and the drive's heartbeat consumer
0x1016 (it faults with 0x8130 when this master goes silent), upload the PDO mapping and check it (RPDO1 =
controlword + target torque, TPDO1 = statusword + torque actual + position actual, TPDO2 = mode display +
error code) → start this master's heartbeat → NMT operational. ``enable()`` writes 0x6072/0x6087/0x6060 = 4 by
SDO, reads 0x6061 back and fails loudly if the mode did not take (canopen's BaseNode402.op_mode only logs),
then walks 0x06 → 0x07 → 0x0F over RPDO1, confirming each state from TPDO1. EMCY frames are recorded; the
drive's FAULT state raises DeviceFault with the EMCY / 0x603F code.

Failures: SDO without answer → InstrumentTimeout; SDO abort → CommandRejected; TPDO of the wrong length →
MalformedReply; no heartbeat for ``heartbeat_timeout_s`` (or a broken socketcand link) → a bounded reconnect
(``reconnect_attempts`` re-opens, each waiting at most ``reconnect_timeout_s`` for the drive's heartbeat), then
Disconnected. Once that bound is spent the link counts as lost: every later call re-probes once, waiting only
``heartbeat_timeout_s`` for a heartbeat, so a dead drive costs each call a short wait, not the whole bound again,
and a drive that comes back is configured again on the next call. Every method on a lost link (or before
``connect()``/after ``close()``) raises Disconnected naming the instrument; ``disable()`` and ``quick_stop()``
with the heartbeat gone but the bus still open send their frames anyway (the drive may still hear them) and
then raise Disconnected, since nothing confirms them. A boot-up message (the drive restarted) makes the
driver configure the drive again. The Loader logic itself (state walk, scaling, ramp-down) is
``drivers.cia402.CiA402Loader``; the link (bus, configuration, heartbeats, reconnect) and the drive's process data
are ``drivers.canopen_link``; this module maps the loader's primitives onto them.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any
from urllib.parse import urlparse

from tcms_daq.drivers.base import Clock, CommandRejected, Disconnected, InstrumentTimeout
from tcms_daq.drivers.canopen_link import TORQUE_LAYOUT, CanopenLink, PdoLayout, Tpdo1
from tcms_daq.drivers.cia402 import CiA402Drive, CiA402Loader
from tcms_daq.drivers.options import CiA402CanopenOptions, CiA402VelocityCanopenOptions
from tcms_daq.drivers.timebase import REAL_TIME, Timebase

from tcms_daq.errors import ConfigError
from tcms_daq.protocols.cia402 import drive_eds_path, to_int16

log = logging.getLogger(__name__)


class _QuietStreamSplits(logging.Filter):
    """python-can's socketcand client warns whenever a TCP read ends inside a frame text; that is normal
    stream behaviour (it waits for the rest), not a fault worth a warning on every run."""

    def filter(self, record: logging.LogRecord) -> bool:
        return "incomplete message" not in record.getMessage()


logging.getLogger("can.interfaces.socketcand.socketcand").addFilter(_QuietStreamSplits())

SETTING_OBJECTS = {"max_torque": 0x6072, "torque_slope": 0x6087, "mode": 0x6060,  # CiA402Loader settings
                   "target_position": 0x607A, "profile_velocity": 0x6081,
                   # the input drive's (drivers.cia402_velocity)
                   "max_profile_velocity": 0x607F, "profile_acceleration": 0x6083, "profile_deceleration": 0x6084,
                   "quick_stop_deceleration": 0x6085}


#: python-can interfaces of real CAN adapters a loader URL may name (``pcan://PCAN_USBBUS1``); network-based
#: software buses other than socketcand are refused: they are not confined to the bench's loopback or bus.
HARDWARE_CAN_INTERFACES = frozenset({
    "socketcan", "pcan", "kvaser", "ixxat", "vector", "slcan", "gs_usb", "nican", "nixnet", "canalystii",
    "seeedstudio", "systec", "usb2can", "neovi", "etas", "cantact", "robotell", "serial",
})


def parse_can_url(url: str, bitrate: int | None = None) -> dict[str, Any]:
    """python-can bus options for a loader URL (see module doc)."""
    parsed = urlparse(url)
    if parsed.scheme == "socketcand":
        channel = parsed.path.strip("/")
        if not (parsed.hostname and parsed.port and channel):
            raise ConfigError(f"CAN URL {url!r}: expected socketcand://host:port/channel")
        return {"interface": "socketcand", "host": parsed.hostname, "port": parsed.port, "channel": channel}
    if parsed.scheme == "virtual":
        channel = (parsed.netloc + parsed.path).strip("/")
        if not channel:
            raise ConfigError(f"CAN URL {url!r}: expected virtual://channel")
        return {"interface": "virtual", "channel": channel}
    if parsed.scheme and parsed.scheme not in HARDWARE_CAN_INTERFACES:
        raise ConfigError(f"CAN URL {url!r}: unsupported CAN interface {parsed.scheme!r} (use socketcand://, "
                          f"virtual:// or a CAN adapter: {', '.join(sorted(HARDWARE_CAN_INTERFACES))})")
    if parsed.scheme and (parsed.netloc or parsed.path):
        options: dict[str, Any] = {"interface": parsed.scheme, "channel": (parsed.netloc + parsed.path).strip("/")}
        if bitrate:
            options["bitrate"] = bitrate
        return options
    raise ConfigError(f"CAN URL {url!r}: expected socketcand://host:port/channel or virtual://channel")


class CanopenWire(CiA402Drive):
    """The CANopen half of a CiA 402 drive: the link — bus, configuration, heartbeats, reconnect — is ``self.link``
    (``drivers.canopen_link.CanopenLink``), what the drive sends by itself ``self.link.process``; this class maps
    the drive's primitives (:class:`drivers.cia402.CiA402Wire`) onto them. ``pdo_layout`` says what the PDOs carry,
    ``default_eds`` which object dictionary a config without ``eds`` gets."""

    pdo_layout: PdoLayout = TORQUE_LAYOUT
    default_eds: Callable[[], Path] = staticmethod(drive_eds_path)

    def __init__(self, options: CiA402CanopenOptions | CiA402VelocityCanopenOptions, *,
                 clock: Clock = time.monotonic, timebase: Timebase = REAL_TIME):
        super().__init__(options, clock=clock, timebase=timebase)
        self.link = CanopenLink(options, parse_can_url(options.url, options.bitrate),
                                str(options.eds or self.default_eds()), timebase, self._configure_scaling,
                                self.pdo_layout)
        self.heartbeat_timeout_s = self.link.heartbeat_timeout_s
        self.master_heartbeat_ms = self.link.master_heartbeat_ms
        self.drive_consumer_timeout_ms = self.link.drive_consumer_timeout_ms

    def connect(self) -> None:
        self.link.connect()

    def close(self) -> None:
        self.link.close()

    @property
    def last_emcy(self) -> tuple[int, int] | None:
        """The drive's last EMCY (code, register), None since connecting or the last fault reset."""
        return self.link.process.last_emcy

    def _latest_tpdo(self) -> Tpdo1:
        """The latest TPDO1 (statusword, torque ‰, position, time), InstrumentTimeout if none or stale."""
        tpdo = self.link.process.wait_tpdo(lambda sw: True, self.state_timeout_s)
        if tpdo is None:
            raise InstrumentTimeout(self.name, "no TPDO1 from the drive")
        if self.timebase.now() - tpdo[3] > self.heartbeat_timeout_s:
            raise InstrumentTimeout(self.name, f"TPDO1 stale for {self.timebase.now() - tpdo[3]:.2f} s")
        return tpdo

    # -- CiA402Loader primitives: SDO settings, RPDO1 commands, TPDO process data ------------------------

    def _ensure_ready(self) -> None:
        self.link.ensure()

    def _stop_link_degraded(self) -> str | None:
        if self.link.node is None:
            self.link.ensure()
        return None if self.link.process.heartbeat_alive() else f"no heartbeat for {self.heartbeat_timeout_s:g} s"

    def _read_statusword(self) -> int:
        return self._latest_tpdo()[0]

    def _read_error_code(self) -> int:
        """The last TPDO2 / EMCY code; 0x603F by SDO when neither told it yet (e.g. just after connecting to a
        drive already in FAULT)."""
        code = self.link.process.error_code()
        if code == 0:
            try:
                code = self.link.sdo_read(0x603F)
            except (InstrumentTimeout, CommandRejected, Disconnected):
                pass
        return code

    def _read_torque_permille(self) -> int:
        return self._latest_tpdo()[1]

    def _read_process(self) -> tuple[int, int, int]:
        statusword, torque_permille, position, _ = self._latest_tpdo()
        return statusword, torque_permille, position

    def _read_mode_display(self) -> int:
        return to_int16(self.link.sdo_read(0x6061))

    def _write_setting(self, name: str, value: int) -> None:
        self.link.sdo_write(SETTING_OBJECTS[name], value)

    def _write_target(self, permille: int) -> None:
        self.link.send_rpdo(self.link.controlword, permille)

    def _reset_target(self) -> None:
        self.link.target_permille = 0  # RPDO1 carries it with the next controlword

    def _write_controlword(self, controlword: int) -> float:
        return self.link.send_rpdo(controlword, self.link.target_permille)

    def _await_statusword(self, predicate: Callable[[int], bool], since: float | None,
                          timeout_s: float) -> tuple[int | None, int]:
        process = self.link.process
        tpdo = process.wait_tpdo(predicate, timeout_s, after=since)
        if tpdo is not None:
            return tpdo[0], tpdo[0]
        with process.cond:
            last = process.tpdo1[0] if process.tpdo1 else 0
        return None, last

    def fault_reset(self) -> None:
        super().fault_reset()
        with self.link.process.cond:
            self.link.process.last_emcy = None


class CiA402Canopen(CanopenWire, CiA402Loader):
    """Loader: a CiA 402 drive in profile torque mode over CANopen (SDO configuration, PDO process data)."""

    options_model = CiA402CanopenOptions
    options: CiA402CanopenOptions

    def __init__(self, options: CiA402CanopenOptions, *, clock: Clock = time.monotonic,
                 timebase: Timebase = REAL_TIME):
        super().__init__(options, clock=clock, timebase=timebase)

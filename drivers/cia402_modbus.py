"""CiA 402 servo loader over Modbus TCP or RTU (pymodbus==3.16.1 synchronous clients): Loader.

The drive's objects sit in holding registers described by a register map (``config/modbus-drive.toml``,
Kinco-style: controlword 0x3100, statusword 0x3200, 32-bit values low word first). URL:

- ``tcp://host:port``                       Modbus TCP (MBAP framing)
- ``socket://host:port``                    RTU frames carried over TCP (simulator, serial-to-Ethernet gateways);
  with ``serial_line=True`` through the serial-line client below (a raw converter in front of an RS-485 line)
- anything else (``/dev/ttyUSB0``, ``rfc2217://…``) a serial line with RTU framing, opened through pyserial
  (``drivers.modbus_rtu.RtuSerialClient``: replies read by their known length, t3.5 kept before each request)

The drive's own communication watchdog: ``connect()`` arms it (``comm_timeout_ms`` into the map's
``comm_timeout`` register, ``abort_connection_option`` into 0x6007), so silence of this master for that long —
a dead service, a cut cable, a hung host — makes the drive react by itself (default: fault 0x8130, torque
off). Every request feeds it; a keep-alive thread reads the statusword when nothing else was sent for a quarter
of the timeout, so the drive is fed while this driver is connected whatever its user does. ``close()`` of a
drive that is not powered disarms it (a commissioning tool may then talk to the drive); ``comm_timeout_ms = 0``
runs without (not recommended: the drive then keeps its torque when the software dies).

Failures: no answer → InstrumentTimeout; a broken answer → MalformedReply; Modbus exception 4 (device failure)
→ DeviceFault, other exception responses → CommandRejected; connection lost and the bounded reconnect failed
→ Disconnected; statusword FAULT → DeviceFault with the drive's error code (0x603F).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from pathlib import Path

from tcms_daq.drivers.base import (
    Clock,
    CommandRejected,
    DeviceFault,
    Disconnected,
    InstrumentTimeout,
    MalformedReply,
)
from tcms_daq.drivers.cia402 import CiA402Drive, CiA402Loader
from tcms_daq.drivers.modbus_link import ModbusDriveLink
from tcms_daq.drivers.options import CiA402ModbusOptions, CiA402VelocityModbusOptions
from tcms_daq.drivers.timebase import REAL_TIME, Timebase

from tcms_daq.errors import ConfigError
from tcms_daq.protocols.cia402 import (
    POWERED_STATES,
    state_from_statusword,
)
from tcms_daq.protocols.modbus_map import (
    DEFAULT_MAP_PATH,
    REQUIRED_REGISTERS,
    RegisterMap,
    load_register_map,
)

log = logging.getLogger(__name__)


class ModbusWire(CiA402Drive):
    """The Modbus half of a CiA 402 drive: register access through the map (``self.link``), the drive's
    communication watchdog armed on connect and fed while connected; this class maps the drive's primitives
    (:class:`drivers.cia402.CiA402Wire`) onto registers. ``default_register_map``: the map a config without
    ``register_map`` gets."""

    default_register_map: Path = DEFAULT_MAP_PATH
    required_registers: tuple[str, ...] = REQUIRED_REGISTERS

    def __init__(self, options: CiA402ModbusOptions | CiA402VelocityModbusOptions, *, clock: Clock = time.monotonic,
                 timebase: Timebase = REAL_TIME, register_map: RegisterMap | None = None,
                 trace_packet: Callable[[bool, bytes], bytes] | None = None):
        """``register_map``: a map already loaded (else ``options.register_map``'s file); ``trace_packet``: sees
        every packet (tests)."""
        super().__init__(options, clock=clock, timebase=timebase)
        self.comm_timeout_ms = options.comm_timeout_ms
        self.abort_connection_option = options.abort_connection_option
        self._rearm = False  # re-arm the watchdog before the next command (after a reconnect)
        if register_map is None:
            register_map = load_register_map(options.register_map or self.default_register_map,
                                             self.required_registers)
        self.link = ModbusDriveLink(options, register_map, timebase, trace_packet, on_reconnect=self._after_reconnect)
        if self.comm_timeout_ms and "comm_timeout" not in self.link.map.registers:
            raise ConfigError(f"{self.name}: the register map has no 'comm_timeout' register: the drive's "
                              "communication watchdog cannot be armed (add the drive's register, or set "
                              "comm_timeout_ms = 0 to run without it: the drive then keeps its torque when this "
                              "software dies)")

    def _after_reconnect(self) -> None:
        self._rearm = bool(self.comm_timeout_ms)

    # -- Loader ------------------------------------------------------------------------------------------

    def connect(self) -> None:
        if not self.link.client.connect():
            raise Disconnected(self.name, f"cannot connect to {self.url}")
        self._configure_scaling(self.link.read_register("rated_torque"))
        self._arm_watchdog()

    def _arm_watchdog(self) -> None:
        """The drive's reaction (0x6007) first, then its timeout; read back, so a drive that ignores the write is
        found now, not when the software dies. Starts the keep-alive thread."""
        if not self.comm_timeout_ms:
            log.warning("%s: communication watchdog off (comm_timeout_ms = 0): the drive keeps its torque if this "
                        "software or its link dies", self.name)
            if "comm_timeout" in self.link.map.registers:  # cleared: an earlier master may have left it armed
                self.link.write_register("comm_timeout", 0)
            return
        if "abort_connection_option" in self.link.map.registers:
            self.link.write_register("abort_connection_option", self.abort_connection_option)
        self.link.write_register("comm_timeout", self.comm_timeout_ms)
        armed = self.link.read_register("comm_timeout")
        if armed != self.comm_timeout_ms:
            raise CommandRejected(self.name, f"communication timeout reads {armed} ms after writing "
                                  f"{self.comm_timeout_ms} ms: the drive's watchdog is not armed")
        self.link.start_keepalive()

    def close(self) -> None:
        """Stop feeding; disarm the drive's watchdog only when the drive is not powered (a drive left enabled
        keeps it armed: it then stops by itself)."""
        self.link.stop_keepalive()
        if self.comm_timeout_ms and self.link.client.connected:
            try:
                if state_from_statusword(self.link.read_register("statusword")) not in POWERED_STATES:
                    self.link.write_register("comm_timeout", 0)
            except (InstrumentTimeout, MalformedReply, DeviceFault, CommandRejected, Disconnected) as exc:
                log.debug("%s: disarming the watchdog on close: %s", self.name, exc)
        self.link.client.close()

    # -- CiA402Loader primitives: one register per object ----------------------------------------------

    def _ensure_ready(self) -> None:
        if self._rearm:
            self._rearm = False
            self._arm_watchdog()

    def _read_statusword(self) -> int:
        return self.link.read_register("statusword")

    def _read_error_code(self) -> int:
        return self.link.read_register("error_code")

    def _read_torque_permille(self) -> int:
        return self.link.read_register("torque_actual")

    def _read_process(self) -> tuple[int, int, int]:
        return (self.link.read_register("statusword"), self.link.read_register("torque_actual"),
                self.link.read_register("position_actual"))

    def _read_mode_display(self) -> int:
        return self.link.read_register("mode_display")

    def _write_setting(self, name: str, value: int) -> None:
        if name not in self.link.map.registers:
            raise CommandRejected(self.name, f"the register map has no {name!r} register (needed for moves: "
                                  "target_position 0x607A and profile_velocity 0x6081)")
        self.link.write_register(name, value)

    def _write_target(self, permille: int) -> None:
        self.link.write_register("target_torque", permille)

    def _write_controlword(self, controlword: int) -> None:
        self.link.write_register("controlword", controlword)

    def _await_statusword(self, predicate: Callable[[int], bool], since: float | None,
                          timeout_s: float) -> tuple[int | None, int]:
        """Poll the statusword (a read after the write's reply always sees the write)."""
        deadline = self.timebase.now() + timeout_s
        while True:
            sw = self.link.read_register("statusword")
            if predicate(sw):
                return sw, sw
            if self.timebase.now() > deadline:
                return None, sw
            self.timebase.sleep(0.005)


class CiA402Modbus(ModbusWire, CiA402Loader):
    """Loader: a CiA 402 drive in profile torque mode over Modbus TCP/RTU."""

    options_model = CiA402ModbusOptions
    options: CiA402ModbusOptions

    def __init__(self, options: CiA402ModbusOptions, *, clock: Clock = time.monotonic,
                 timebase: Timebase = REAL_TIME, register_map: RegisterMap | None = None,
                 trace_packet: Callable[[bool, bytes], bytes] | None = None):
        super().__init__(options, clock=clock, timebase=timebase, register_map=register_map,
                         trace_packet=trace_packet)

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
import threading
import time
from collections.abc import Callable
from urllib.parse import urlparse

from pymodbus import FramerType
from pymodbus.client import ModbusTcpClient
from pymodbus.exceptions import ConnectionException, ModbusException, ModbusIOException
from tcms_daq.drivers.base import (
    Clock,
    CommandRejected,
    DeviceFault,
    Disconnected,
    InstrumentTimeout,
    MalformedReply,
)
from tcms_daq.drivers.cia402 import CiA402Loader
from tcms_daq.drivers.modbus_rtu import RtuSerialClient
from tcms_daq.drivers.options import CiA402ModbusOptions
from tcms_daq.drivers.timebase import REAL_TIME, Timebase

from tcms_daq.errors import ConfigError
from tcms_daq.protocols.cia402 import (
    POWERED_STATES,
    state_from_statusword,
)
from tcms_daq.protocols.modbus_map import RegisterMap, load_register_map

log = logging.getLogger(__name__)

EXCEPTION_NAMES = {1: "illegal function", 2: "illegal data address", 3: "illegal data value",
                   4: "device failure", 6: "device busy", 10: "gateway path unavailable",
                   11: "gateway target did not respond"}




# -- the driver -------------------------------------------------------------------------------------------------

def make_client(url: str, *, timeout_s: float, retries: int, baudrate: int, trace_packet=None,
                serial_line: bool = False, timebase: Timebase = REAL_TIME):
    """A pymodbus sync client for ``url`` (see module doc); automatic background reconnect is off.

    ``serial_line``: a ``socket://`` URL gets the serial-line client too (t3.5 kept between frames), for a raw
    serial-to-Ethernet converter that passes bytes straight onto an RS-485 line."""
    parsed = urlparse(url)
    common = dict(timeout=timeout_s, retries=retries, reconnect_delay=0, trace_packet=trace_packet)
    if parsed.scheme == "tcp" or (parsed.scheme == "socket" and not serial_line):
        if not parsed.hostname:
            raise ConfigError(f"Modbus URL {url!r} lacks a host")
        # socket:// = RTU frames carried over TCP (serial-to-Ethernet gateway, the simulator): the TCP client with
        # the RTU framer reads replies as they arrive, where the serial client polls the line for silence
        framer = FramerType.SOCKET if parsed.scheme == "tcp" else FramerType.RTU
        return ModbusTcpClient(parsed.hostname, port=parsed.port or 502, framer=framer, **common)
    return RtuSerialClient(url, baudrate=baudrate, bytesize=8, parity="N", stopbits=1, timebase=timebase, **common)


class CiA402Modbus(CiA402Loader):
    """Loader: a CiA 402 drive in profile torque mode over Modbus TCP/RTU."""

    options_model = CiA402ModbusOptions

    def __init__(self, options: CiA402ModbusOptions, *, clock: Clock = time.monotonic,
                 timebase: Timebase = REAL_TIME, register_map: RegisterMap | None = None,
                 trace_packet: Callable[[bool, bytes], bytes] | None = None):
        """``register_map``: a map already loaded (else ``options.register_map``'s file); ``trace_packet``: sees
        every packet (tests)."""
        super().__init__(name=options.name, max_torque_nm=options.max_torque_nm,
                         torque_slope_nm_per_s=options.torque_slope_nm_per_s, state_timeout_s=options.state_timeout_s,
                         clock=clock, timebase=timebase)
        self.options = options
        name, url, timeout_s = options.name, options.url, options.timeout_s
        comm_timeout_ms = options.comm_timeout_ms
        self.counts_per_rev = options.counts_per_rev
        self.move_torque_window_nm = options.move_torque_window_nm
        self.url = url
        self.map = register_map if register_map is not None else load_register_map(options.register_map)
        self.device_id = self.map.device_id if options.device_id is None else options.device_id
        self.timeout_s = timeout_s
        self.reconnect_attempts = options.reconnect_attempts
        self.reconnect_delay_s = options.reconnect_delay_s
        self._user_trace = trace_packet
        self._rx_seen = b""  # reply bytes seen during the current call (tells "garbage" from "silence")
        self.client = make_client(url, timeout_s=timeout_s, retries=options.retries, baudrate=options.baudrate,
                                  trace_packet=self._trace, serial_line=options.serial_line, timebase=timebase)
        self.reconnects = 0
        self.comm_timeout_ms = comm_timeout_ms
        self.abort_connection_option = options.abort_connection_option
        if comm_timeout_ms and "comm_timeout" not in self.map.registers:
            raise ConfigError(f"{name}: the register map has no 'comm_timeout' register: the drive's communication "
                              "watchdog cannot be armed (add the drive's register, or set comm_timeout_ms = 0 to run "
                              "without it: the drive then keeps its torque when this software dies)")
        # one request at a time on the client: the keep-alive thread shares it with the user's calls
        self._io_lock = threading.RLock()
        self._last_request = time.monotonic()  # real time: the drive's watchdog counts real time
        self._keepalive: threading.Thread | None = None
        self._keepalive_stop = threading.Event()
        self._rearm = False  # re-arm the watchdog before the next command (after a reconnect)

    # -- Modbus access with error mapping --------------------------------------------------------------

    def _trace(self, sending: bool, data: bytes) -> bytes:
        if not sending and len(data) > len(self._rx_seen):
            self._rx_seen = bytes(data[:256])
        return self._user_trace(sending, data) if self._user_trace is not None else data

    def _call(self, what: str, func, *args, **kwargs):
        with self._io_lock:
            try:
                return self._call_locked(what, func, *args, **kwargs)
            finally:
                self._last_request = time.monotonic()

    def _call_locked(self, what: str, func, *args, **kwargs):
        for attempt in range(2):
            self._rx_seen = b""
            try:
                if not self.client.connected and not self.client.connect():
                    raise ConnectionException(f"cannot connect to {self.url}")
                response = func(*args, device_id=self.device_id, **kwargs)
            except ConnectionException as exc:
                if attempt == 0:
                    self._reconnect(exc)
                    continue
                raise Disconnected(self.name, f"{what}: {exc}") from exc
            except ModbusIOException as exc:
                text = str(exc)
                if "No response" in text and self._rx_seen:
                    raise MalformedReply(
                        self.name, f"{what}: reply bytes {self._rx_seen[:32].hex(' ')} do not form a valid frame"
                    ) from exc
                if "No response" in text:
                    raise InstrumentTimeout(self.name, f"{what}: no response within {self.timeout_s:g} s") from exc
                raise MalformedReply(self.name, f"{what}: {text}") from exc
            except ModbusException as exc:
                raise MalformedReply(self.name, f"{what}: {exc}") from exc
            except (OSError, ValueError) as exc:
                if attempt == 0:
                    self._reconnect(exc)
                    continue
                raise Disconnected(self.name, f"{what}: {exc}") from exc
            if response is None:
                raise InstrumentTimeout(self.name, f"{what}: no response")
            if response.isError():
                code = getattr(response, "exception_code", None)
                name = EXCEPTION_NAMES.get(code, "unknown") if isinstance(code, int) else "unknown"
                text = f"{what}: Modbus exception {code} ({name})"
                if code == 4:
                    raise DeviceFault(self.name, text, code=code)
                if code in (10, 11):
                    raise InstrumentTimeout(self.name, text)
                raise CommandRejected(self.name, text)
            return response
        raise AssertionError("unreachable")

    def _reconnect(self, reason: BaseException) -> None:
        self.client.close()
        for attempt in range(self.reconnect_attempts):
            if attempt:
                self.timebase.sleep(self.reconnect_delay_s)
            if self.client.connect():
                self.reconnects += 1
                self._rearm = bool(self.comm_timeout_ms)  # the drive may have restarted with its own setting
                return
        raise Disconnected(
            self.name, f"link to {self.url} lost ({reason}); {self.reconnect_attempts} reconnect attempts failed"
        )

    def read_register(self, name: str) -> int:
        spec = self.map[name]
        rr = self._call(f"read {name} @0x{spec.address:04X}", self.client.read_holding_registers,
                        spec.address, count=spec.words)
        if len(rr.registers) != spec.words:
            raise MalformedReply(self.name, f"read {name}: {len(rr.registers)} registers, expected {spec.words}")
        return self.map.decode(name, rr.registers)

    def write_register(self, name: str, value: int) -> None:
        spec = self.map[name]
        try:
            words = self.map.encode(name, value)
        except ValueError as exc:
            raise CommandRejected(self.name, str(exc)) from None
        what = f"write {name} @0x{spec.address:04X} = {value}"
        if spec.words == 1:
            self._call(what, self.client.write_register, spec.address, words[0])
        else:
            self._call(what, self.client.write_registers, spec.address, words)

    # -- Loader ------------------------------------------------------------------------------------------

    def connect(self) -> None:
        if not self.client.connect():
            raise Disconnected(self.name, f"cannot connect to {self.url}")
        self._configure_scaling(self.read_register("rated_torque"))
        self._arm_watchdog()

    def _arm_watchdog(self) -> None:
        """The drive's reaction (0x6007) first, then its timeout; read back, so a drive that ignores the write is
        found now, not when the software dies. Starts the keep-alive thread."""
        if not self.comm_timeout_ms:
            log.warning("%s: communication watchdog off (comm_timeout_ms = 0): the drive keeps its torque if this "
                        "software or its link dies", self.name)
            return
        if "abort_connection_option" in self.map.registers:
            self.write_register("abort_connection_option", self.abort_connection_option)
        self.write_register("comm_timeout", self.comm_timeout_ms)
        armed = self.read_register("comm_timeout")
        if armed != self.comm_timeout_ms:
            raise CommandRejected(self.name, f"communication timeout reads {armed} ms after writing "
                                  f"{self.comm_timeout_ms} ms: the drive's watchdog is not armed")
        self._start_keepalive()

    def _start_keepalive(self) -> None:
        if self._keepalive is not None and self._keepalive.is_alive():
            return
        self._keepalive_stop.clear()
        self._keepalive = threading.Thread(target=self._feed_watchdog, name=f"modbus-keepalive-{self.url}",
                                           daemon=True)
        self._keepalive.start()

    def _feed_watchdog(self) -> None:
        """Keep-alive (own thread): a statusword read whenever nothing was sent for a quarter of the timeout. A
        request already under way feeds the drive by itself, so the thread never queues behind one."""
        period_s = self.comm_timeout_ms / 4000.0
        while not self._keepalive_stop.wait(period_s / 2):
            if time.monotonic() - self._last_request < period_s or not self.client.connected:
                continue
            if not self._io_lock.acquire(blocking=False):
                continue
            try:
                self._call_locked("keep-alive read statusword", self.client.read_holding_registers,
                                  self.map["statusword"].address, count=1)
            except Exception as exc:  # noqa: BLE001 - the user's own calls report the link's errors
                log.debug("%s: keep-alive: %s", self.name, exc)
            finally:
                self._last_request = time.monotonic()
                self._io_lock.release()

    def _stop_keepalive(self) -> None:
        self._keepalive_stop.set()
        thread, self._keepalive = self._keepalive, None
        if thread is not None and thread is not threading.current_thread():
            thread.join(max(1.0, 2 * self.timeout_s))

    def close(self) -> None:
        """Stop feeding; disarm the drive's watchdog only when the drive is not powered (a drive left enabled
        keeps it armed: it then stops by itself)."""
        self._stop_keepalive()
        if self.comm_timeout_ms and self.client.connected:
            try:
                if state_from_statusword(self.read_register("statusword")) not in POWERED_STATES:
                    self.write_register("comm_timeout", 0)
            except (InstrumentTimeout, MalformedReply, DeviceFault, CommandRejected, Disconnected) as exc:
                log.debug("%s: disarming the watchdog on close: %s", self.name, exc)
        self.client.close()

    # -- CiA402Loader primitives: one register per object ----------------------------------------------

    def _ensure_ready(self) -> None:
        if self._rearm:
            self._rearm = False
            self._arm_watchdog()

    def _read_statusword(self) -> int:
        return self.read_register("statusword")

    def _read_error_code(self) -> int:
        return self.read_register("error_code")

    def _read_torque_permille(self) -> int:
        return self.read_register("torque_actual")

    def _read_process(self) -> tuple[int, int, int]:
        return (self.read_register("statusword"), self.read_register("torque_actual"),
                self.read_register("position_actual"))

    def _read_mode_display(self) -> int:
        return self.read_register("mode_display")

    def _write_setting(self, name: str, value: int) -> None:
        if name not in self.map.registers:
            raise CommandRejected(self.name, f"the register map has no {name!r} register (needed for moves: "
                                  "target_position 0x607A and profile_velocity 0x6081)")
        self.write_register(name, value)

    def _write_target(self, permille: int) -> None:
        self.write_register("target_torque", permille)

    def _write_controlword(self, controlword: int) -> None:
        self.write_register("controlword", controlword)

    def _await_statusword(self, predicate: Callable[[int], bool], since: float | None,
                          timeout_s: float) -> tuple[int | None, int]:
        """Poll the statusword (a read after the write's reply always sees the write)."""
        deadline = self.timebase.now() + timeout_s
        while True:
            sw = self.read_register("statusword")
            if predicate(sw):
                return sw, sw
            if self.timebase.now() > deadline:
                return None, sw
            self.timebase.sleep(0.005)

"""The Modbus link to one CiA 402 drive (pymodbus==3.16.1 synchronous clients), below the loader
(``drivers.cia402_modbus.CiA402Modbus``): the client for a URL, register access through the register map with the
driver's error types and a bounded reconnect, one request at a time, and the keep-alive thread that feeds the
drive's communication watchdog while nothing else is sent. The URL forms and the failure semantics are the loader
module's docstring.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import Any
from urllib.parse import urlparse

from pymodbus import FramerType
from pymodbus.client import ModbusTcpClient
from pymodbus.exceptions import ConnectionException, ModbusException, ModbusIOException
from tcms_daq.drivers.base import (
    CommandRejected,
    DeviceFault,
    Disconnected,
    InstrumentTimeout,
    MalformedReply,
)
from tcms_daq.drivers.modbus_rtu import RtuSerialClient
from tcms_daq.drivers.options import ModbusLinkOptions
from tcms_daq.drivers.timebase import REAL_TIME, Timebase

from tcms_daq.errors import ConfigError
from tcms_daq.protocols.modbus_map import RegisterMap

log = logging.getLogger("tcms_daq.drivers.cia402_modbus")

EXCEPTION_NAMES = {1: "illegal function", 2: "illegal data address", 3: "illegal data value",
                   4: "device failure", 6: "device busy", 10: "gateway path unavailable",
                   11: "gateway target did not respond"}


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


class ModbusDriveLink:
    """Register access to one drive: ``read_register`` / ``write_register`` by map name, one request at a time
    (the keep-alive thread shares the client), errors as the driver's types, a lost connection re-opened within
    ``reconnect_attempts`` (``on_reconnect`` is called after each success), and the keep-alive feeding the drive's
    watchdog every quarter of ``comm_timeout_ms`` of silence."""

    def __init__(self, options: ModbusLinkOptions, register_map: RegisterMap, timebase: Timebase,
                 trace_packet: Callable[[bool, bytes], bytes] | None, on_reconnect: Callable[[], None]):
        self.name = options.name
        self.url = options.url
        self.map = register_map
        self.device_id = self.map.device_id if options.device_id is None else options.device_id
        self.timeout_s = options.timeout_s
        self.reconnect_attempts = options.reconnect_attempts
        self.reconnect_delay_s = options.reconnect_delay_s
        self.comm_timeout_ms = options.comm_timeout_ms
        self.timebase = timebase
        self._on_reconnect = on_reconnect
        self._user_trace = trace_packet
        self._rx_seen = b""  # reply bytes seen during the current call (tells "garbage" from "silence")
        self.client = make_client(options.url, timeout_s=options.timeout_s, retries=options.retries,
                                  baudrate=options.baudrate, trace_packet=self._trace,
                                  serial_line=options.serial_line, timebase=timebase)
        self.reconnects = 0
        # one request at a time on the client: the keep-alive thread shares it with the user's calls
        self._io_lock = threading.RLock()
        self._last_request = time.monotonic()  # real time: the drive's watchdog counts real time
        self._keepalive: threading.Thread | None = None
        self._keepalive_stop = threading.Event()

    def _trace(self, sending: bool, data: bytes) -> bytes:
        if not sending and len(data) > len(self._rx_seen):
            self._rx_seen = bytes(data[:256])
        return self._user_trace(sending, data) if self._user_trace is not None else data

    def _call(self, what: str, func: Callable[..., Any], *args: object, **kwargs: object) -> Any:
        with self._io_lock:
            try:
                return self._call_locked(what, func, *args, **kwargs)
            finally:
                self._last_request = time.monotonic()

    def _call_locked(self, what: str, func: Callable[..., Any], *args: object, **kwargs: object) -> Any:
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
                self._on_reconnect()  # the drive may have restarted with its own setting
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

    # -- the keep-alive (own thread) ---------------------------------------------------------------------

    def start_keepalive(self) -> None:
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

    def stop_keepalive(self) -> None:
        self._keepalive_stop.set()
        thread, self._keepalive = self._keepalive, None
        if thread is not None and thread is not threading.current_thread():
            thread.join(max(1.0, 2 * self.timeout_s))

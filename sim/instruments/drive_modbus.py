"""Modbus front end of the simulated CiA 402 drive (pymodbus 3.16.1 server, TCP or RTU framing).

Holding registers follow the register map (``config/modbus-drive.toml``); addresses outside the map answer
exception 2. The SimDevice ``action`` refreshes measured registers from the drive model on every read and
pushes writes into it; writes to read-only registers → exception 2, values the drive refuses → exception 3
(4 when refused in the present state). Fault injection: ``inject("mute")`` makes the server swallow requests
(the client times out). Several drives may share one server at their maps' device ids (the second axis's input
drive at unit id 2 beside the loader at 1: one RS-485 line or one gateway); each has its own watchdog.

Communication watchdog, as a real drive's connection monitoring: once this front end has had a request, a
silence longer than the drive's communication timeout (``Drive402Model.comm_timeout_ms``, the ``comm_timeout``
register; 0 = off) makes the drive react as its abort connection option code 0x6007 says (``abort_connection_option``
register; fault 0x8130 by default) — once per silence, and only while the drive is powering the load. A front
end that never had a request (the RTU port while a master uses TCP) does not watch.
"""

from __future__ import annotations

import asyncio
import contextlib
import socket
import time
from collections.abc import Sequence

from pymodbus import FramerType
from pymodbus.constants import ExcCodes
from pymodbus.exceptions import NoSuchIdException
from pymodbus.server import ModbusSerialServer, ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice
from tcms_daq.sim.instruments.drive402 import Drive402Model, DriveCommandError

from tcms_daq.protocols.modbus_map import RegisterMap

FAULTS = ("mute",)


def _free_port(host: str) -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((host, 0))
        return s.getsockname()[1]


class DriveFront:
    """One drive behind the server, at its register map's device id: register access, its requests and its
    communication watchdog's record."""

    def __init__(self, server: DriveModbusServer, drive: Drive402Model, regmap: RegisterMap):
        self.server = server
        self.drive = drive
        self.map = regmap
        self.requests = 0
        self._by_address = regmap.by_address()
        self._last_request: float | None = None  # None: no request since start, or the watchdog reacted
        # what the watchdog did and when (time.monotonic(), system-wide): tests and the control channel
        self.watchdog_reactions: list[dict[str, float | str]] = []

    def _value(self, name: str) -> int:
        getter = self.drive.register_getters().get(name)
        return getter() if getter is not None else 0

    def _write(self, name: str, value: int) -> None:
        setter = self.drive.register_setters().get(name)
        if setter is None:
            raise DriveCommandError(f"{name} is read-only", kind="readonly")
        setter(value)

    async def _action(self, function_code, start_address, address, count, registers, set_values):
        if self.server.fault == "mute":
            raise NoSuchIdException("muted by fault injection")  # the server then sends nothing
        self.requests += 1
        self._last_request = time.monotonic()
        with self.drive.lock:
            names = []
            for a in range(address, address + count):
                spec, _ = self._by_address[a]
                if spec.name not in names:
                    names.append(spec.name)
            if set_values is None:
                for name in names:
                    spec = self.map[name]
                    words = self.map.encode(name, self._value(name)) if self._fits(name) else [0] * spec.words
                    registers[spec.address - start_address: spec.address - start_address + spec.words] = words
                return None
            pending: dict[str, None] = {}  # names of the registers written, in order
            for i in range(len(set_values)):
                spec, _ = self._by_address[address + i]
                if not spec.writable:
                    return ExcCodes.ILLEGAL_ADDRESS
                pending.setdefault(spec.name, None)
            # assemble whole values (a 32-bit register may be written one word at a time)
            for name in pending:
                spec = self.map[name]
                base = spec.address - start_address
                words = list(registers[base: base + spec.words])
                for i, value in enumerate(set_values):
                    a = address + i
                    if spec.address <= a < spec.address + spec.words:
                        words[a - spec.address] = int(value) & 0xFFFF
                try:
                    self._write(name, self.map.decode(name, words))
                except DriveCommandError as exc:
                    return ExcCodes.DEVICE_FAILURE if exc.kind == "state" else ExcCodes.ILLEGAL_VALUE
            return None

    def _fits(self, name: str) -> bool:
        try:
            self.map.encode(name, self._value(name))
            return True
        except ValueError:
            return False

    def device(self) -> SimDevice:
        blocks = [
            SimData(spec.address, count=spec.words, values=0, datatype=DataType.REGISTERS)
            for spec in sorted(self.map.registers.values(), key=lambda s: s.address)
        ]
        return SimDevice(id=self.map.device_id, action=self._action, simdata=blocks)

    def check_watchdog(self) -> None:
        timeout_s = self.drive.comm_timeout_ms / 1000.0
        last = self._last_request
        if timeout_s <= 0 or last is None or time.monotonic() - last <= timeout_s:
            return
        self._last_request = None  # one reaction per silence
        reaction = self.drive.communication_lost()
        if reaction is not None:
            self.watchdog_reactions.append({"reaction": reaction, "at_monotonic_s": time.monotonic(),
                                            "silent_s": time.monotonic() - last})


class DriveModbusServer:
    """The drives of one Modbus server (one TCP port or RTU line): the loader at its map's device id and, optionally,
    more drives at theirs (``more``: the second axis's input drive at unit id 2)."""

    name = "drive Modbus sim"

    def __init__(
        self,
        drive: Drive402Model,
        regmap: RegisterMap,
        *,
        host: str = "127.0.0.1",
        port: int = 0,
        framer: str = "tcp",
        more: Sequence[tuple[Drive402Model, RegisterMap]] = (),
    ):
        if framer not in ("tcp", "rtu"):
            raise ValueError(f"framer must be 'tcp' or 'rtu', got {framer!r}")
        self.fronts = [DriveFront(self, drive, regmap)] + [DriveFront(self, d, m) for d, m in more]
        ids = [f.map.device_id for f in self.fronts]
        if len(set(ids)) != len(ids):
            raise ValueError(f"drives on one Modbus server need distinct device ids, got {ids}")
        self.drive = drive
        self.map = regmap
        self.host = host
        self.port = port
        self.framer = framer
        self.fault: str | None = None
        self._server: ModbusTcpServer | ModbusSerialServer | None = None
        self._watchdog: asyncio.Task | None = None

    @property
    def requests(self) -> int:
        return sum(f.requests for f in self.fronts)

    @property
    def watchdog_reactions(self) -> list[dict[str, float | str]]:
        """What the drives' watchdogs did, in order (``device_id`` names the drive)."""
        found = [{**r, "device_id": f.map.device_id} for f in self.fronts for r in f.watchdog_reactions]
        return sorted(found, key=lambda r: float(r["at_monotonic_s"]))

    def inject(self, fault: str | None) -> None:
        if fault is not None and fault not in FAULTS:
            raise ValueError(f"{self.name}: unknown fault {fault!r} (known: {', '.join(FAULTS)})")
        self.fault = fault

    def _devices(self) -> list[SimDevice]:
        return [f.device() for f in self.fronts]

    # -- lifecycle -------------------------------------------------------------------------------------

    @property
    def running(self) -> bool:
        return self._server is not None

    async def start(self) -> int:
        if self._server is not None:
            return self.port
        server: ModbusTcpServer | ModbusSerialServer
        if self.framer == "tcp":
            server = ModbusTcpServer(self._devices(), address=(self.host, self.port), ignore_missing_devices=True)
            await server.serve_forever(background=True)
            # pymodbus keeps the asyncio server as ``transport`` once it listens
            self.port = server.transport.sockets[0].getsockname()[1]  # type: ignore[attr-defined]
        else:
            if self.port == 0:
                self.port = _free_port(self.host)
            server = ModbusSerialServer(
                self._devices(), framer=FramerType.RTU, port=f"socket://{self.host}:{self.port}",
                baudrate=115200, ignore_missing_devices=True,
            )
            await server.serve_forever(background=True)
        self._server = server
        for front in self.fronts:
            front._last_request = None
        self._watchdog = asyncio.create_task(self._watch())
        return self.port

    async def stop(self) -> None:
        server, self._server = self._server, None
        if self._watchdog is not None:
            self._watchdog.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._watchdog
            self._watchdog = None
        if server is not None:
            await server.shutdown()

    async def _watch(self) -> None:
        while True:
            timeouts = [f.drive.comm_timeout_ms / 1000.0 for f in self.fronts]
            shortest = min((t for t in timeouts if t > 0), default=0.0)
            await asyncio.sleep(min(0.05, shortest / 4) if shortest > 0 else 0.05)
            for front in self.fronts:
                front.check_watchdog()

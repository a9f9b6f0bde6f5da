"""All instrument simulators of one bench on one shared physics + clock (what ``tcms sim serve`` runs).

``InstrumentSimulators(physics, ...)`` starts, on one asyncio loop thread: the ND 287 server, the AED server,
the CiA 402 drive's Modbus TCP server (and optionally an RTU-over-TCP server), and for CANopen either a
loopback socketcand hub (cross-process) with the drive's LocalNode attached to it, or the LocalNode alone on an
in-process python-can ``virtual`` channel (tests). ``ports`` reports what was bound (0 = ephemeral).
Fault injection: ``inject(instrument, fault)`` and the objects themselves (``nd287``, ``aed``, ``drive``,
``modbus``, ``canopen``, ``hub``).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from tcms_daq.sim.instruments.aed import AEDServer
from tcms_daq.sim.instruments.loop import LoopThread
from tcms_daq.sim.instruments.nd287 import ND287Server
from tcms_daq.sim.instruments.physics import SharedPhysics

if TYPE_CHECKING:
    from tcms_daq.sim.instruments.drive402 import Drive402Model
    from tcms_daq.sim.instruments.drive_canopen import DriveCanopenNode
    from tcms_daq.sim.instruments.drive_modbus import DriveModbusServer
    from tcms_daq.sim.instruments.socketcand_hub import SocketcandHub

log = logging.getLogger(__name__)

DEFAULT_PORTS = {"nd287": 4001, "aed": 4002, "modbus": 5020, "socketcand": 29536}
INSTRUMENTS = ("nd287", "aed", "modbus", "modbus_rtu", "canopen")


@dataclass
class SimulatorOptions:
    """Settings of the simulated instruments (``[sim.instruments]`` in a bench config, all optional)."""

    host: str = "127.0.0.1"
    ports: dict[str, int] = field(default_factory=lambda: dict(DEFAULT_PORTS))
    instruments: tuple[str, ...] = ("nd287", "aed", "modbus", "canopen")
    nd287_unit: str = "G"
    nd287_decimals: int = 5
    nd287_reply_delay_s: float = 0.0
    aed_nominal_torque_nm: float = 2000.0
    aed_reply_delay_s: float = 0.0
    # the drive
    node_id: int = 1
    can_channel: str = "can0"
    can_interface: str = "socketcand"  # "socketcand" (loopback hub, cross-process) or "virtual" (in-process)
    rated_torque_nm: float = 2000.0
    max_torque_permille: int = 1000
    counts_per_rev: int = 1 << 20
    heartbeat_ms: int = 100
    modbus_map: str | None = None  # path of the register map TOML; None = config/modbus-drive.toml
    # the drive's communication watchdog as it leaves the factory (the master sets its own over the link):
    # Modbus silence (s) before it reacts (0 = off), and its reaction (0x6007: 1 fault, 2 disable, 3 quick stop)
    modbus_comm_timeout_s: float = 1.0
    abort_connection_option: int = 1

    @staticmethod
    def from_mapping(data: dict[str, Any], **overrides: Any) -> SimulatorOptions:
        opts = SimulatorOptions()
        for key, value in {**data, **overrides}.items():
            if value is None:
                continue
            if not hasattr(opts, key):
                raise ValueError(f"unknown simulator option {key!r}")
            if key == "ports":
                merged = dict(opts.ports)
                for name, port in value.items():
                    if name not in DEFAULT_PORTS and name != "modbus_rtu":
                        raise ValueError(f"unknown simulator port {name!r} (known: {', '.join(DEFAULT_PORTS)})")
                    merged[name] = int(port)
                value = merged
            elif key == "instruments":
                value = tuple(value)
                unknown = set(value) - set(INSTRUMENTS)
                if unknown:
                    raise ValueError(f"unknown simulated instrument(s) {sorted(unknown)} (known: {INSTRUMENTS})")
            setattr(opts, key, value)
        return opts


class InstrumentSimulators:
    """Start/stop all simulated instruments of one bench; every server shares ``physics``."""

    def __init__(self, physics: SharedPhysics, options: SimulatorOptions | None = None):
        self.physics = physics
        self.options = options or SimulatorOptions()
        self.loop: LoopThread | None = None
        self.nd287: ND287Server | None = None
        self.aed: AEDServer | None = None
        self.drive: Drive402Model | None = None
        self.modbus: DriveModbusServer | None = None
        self.modbus_rtu: DriveModbusServer | None = None
        self.canopen: DriveCanopenNode | None = None
        self.hub: SocketcandHub | None = None
        self.ports: dict[str, int] = {}

    @property
    def running_loop(self) -> LoopThread:
        """The asyncio loop thread of started simulators (RuntimeError before ``start``)."""
        if self.loop is None:
            raise RuntimeError("the simulators are not started")
        return self.loop

    def _require(self, obj: Any, what: str) -> Any:
        if obj is None:
            raise ValueError(f"no running simulated {what}")
        return obj

    # -- lifecycle -------------------------------------------------------------------------------------

    def start(self) -> dict[str, int]:
        opts = self.options
        self.loop = loop = LoopThread()
        try:
            want = set(opts.instruments)
            if "nd287" in want:
                self.nd287 = ND287Server(
                    lambda: self.physics.latest().angle_arcsec,
                    host=opts.host,
                    port=opts.ports.get("nd287", 0),
                    unit=opts.nd287_unit,
                    decimals=opts.nd287_decimals,
                    reply_delay_s=opts.nd287_reply_delay_s,
                )
                self.ports["nd287"] = loop.run(self.nd287.start())
            if "aed" in want:
                self.aed = AEDServer(
                    lambda: self.physics.latest().torque_nm,
                    nominal_torque_nm=opts.aed_nominal_torque_nm,
                    host=opts.host,
                    port=opts.ports.get("aed", 0),
                    reply_delay_s=opts.aed_reply_delay_s,
                )
                self.ports["aed"] = loop.run(self.aed.start())
            if want & {"modbus", "modbus_rtu", "canopen"}:
                self._start_drive(want)
        except BaseException:
            self.stop()
            raise
        return dict(self.ports)

    def _start_drive(self, want: set[str]) -> None:
        from tcms_daq.sim.instruments.drive402 import Drive402Model

        opts = self.options
        loop = self.running_loop
        self.drive = drive = Drive402Model(
            self.physics,
            rated_torque_mnm=round(opts.rated_torque_nm * 1000),
            max_torque_permille=opts.max_torque_permille,
            counts_per_rev=opts.counts_per_rev,
            comm_timeout_ms=round(opts.modbus_comm_timeout_s * 1000),
            abort_connection_option=opts.abort_connection_option,
        )
        if "modbus" in want or "modbus_rtu" in want:
            from tcms_daq.sim.instruments.drive_modbus import DriveModbusServer

            from tcms_daq.protocols.modbus_map import load_register_map

            regmap = load_register_map(Path(opts.modbus_map) if opts.modbus_map else None)
            if "modbus" in want:
                self.modbus = modbus = DriveModbusServer(
                    drive, regmap, host=opts.host, port=opts.ports.get("modbus", 0),
                )
                self.ports["modbus"] = loop.run(modbus.start())
            if "modbus_rtu" in want:
                self.modbus_rtu = modbus_rtu = DriveModbusServer(
                    drive, regmap, host=opts.host, port=opts.ports.get("modbus_rtu", 0), framer="rtu",
                )
                self.ports["modbus_rtu"] = loop.run(modbus_rtu.start())
        if "canopen" in want:
            from tcms_daq.sim.instruments.drive_canopen import DriveCanopenNode

            if opts.can_interface == "socketcand":
                from tcms_daq.sim.instruments.socketcand_hub import SocketcandHub

                self.hub = hub = SocketcandHub(host=opts.host, port=opts.ports.get("socketcand", 0))
                self.ports["socketcand"] = loop.run(hub.start())
                bus_options: dict[str, Any] = {
                    "interface": "socketcand", "channel": opts.can_channel,
                    "host": opts.host, "port": self.ports["socketcand"], "tcp_tune": True,  # TCP_NODELAY
                }
            elif opts.can_interface == "virtual":
                bus_options = {"interface": "virtual", "channel": opts.can_channel}
            else:
                raise ValueError(f"can_interface must be 'socketcand' or 'virtual', got {opts.can_interface!r}")
            self.canopen = canopen_node = DriveCanopenNode(
                drive, node_id=opts.node_id, heartbeat_ms=opts.heartbeat_ms, **bus_options
            )
            canopen_node.start()

    def stop(self) -> None:
        if self.canopen is not None:
            self.canopen.stop()
        if self.loop is not None:
            for server in (self.nd287, self.aed, self.modbus, self.modbus_rtu, self.hub):
                if server is not None:
                    try:
                        self.loop.run(server.stop(), 5.0)
                    except Exception as exc:  # noqa: BLE001 - keep stopping the others
                        log.warning("stopping %s: %s", server, exc)
            self.loop.close()
            self.loop = None
        if self.drive is not None:
            self.drive.detach()

    def __enter__(self) -> InstrumentSimulators:
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    # -- control hooks (tests, the control port) -------------------------------------------------------

    def server(self, instrument: str):
        obj = {"nd287": self.nd287, "aed": self.aed, "modbus": self.modbus, "modbus_rtu": self.modbus_rtu,
               "hub": self.hub, "socketcand": self.hub}.get(instrument)
        if obj is None:
            raise ValueError(f"no running simulated instrument {instrument!r}")
        return obj

    def restart(self, instrument: str) -> None:
        """Stop and re-start one server on the same port (the instrument was power-cycled: the ND 287 comes back
        without its datum and with its power-on settings, the AED with its power-on settings).
        ``canopen`` power-cycles the drive and its CAN node (the socketcand hub keeps running)."""
        if instrument == "canopen":
            self._require(self.canopen, "CANopen drive").restart()
            return
        self.stop_server(instrument)
        self.start_server(instrument)

    def stop_server(self, instrument: str) -> None:
        """Stop one server; for ``socketcand`` the drive's CAN node goes down with the hub it is attached to."""
        if instrument in ("socketcand", "hub") and self.canopen is not None:
            self.canopen.stop()
        self.running_loop.run(self.server(instrument).stop())

    def start_server(self, instrument: str) -> None:
        self.running_loop.run(self.server(instrument).start())
        if instrument in ("socketcand", "hub") and self.canopen is not None:
            self._require(self.drive, "drive").power_cycle()
            self.canopen.start()

    def watchdog_reactions(self) -> list[dict[str, float | str]]:
        """What the drive's communication watchdogs did (Modbus timeout, CANopen heartbeat consumer), in order:
        ``{"link", "reaction", "at_monotonic_s", "silent_s"}``."""
        found = [{"link": "modbus", **r} for server in (self.modbus, self.modbus_rtu) if server is not None
                 for r in server.watchdog_reactions]
        if self.canopen is not None:
            found += [{"link": "canopen", **r} for r in self.canopen.consumer_reactions]
        return sorted(found, key=lambda r: float(r["at_monotonic_s"]))

    def inject(self, instrument: str, fault: str | None) -> None:
        """Fault injection by name: nd287/aed: mute, garbage, partial, encoder_fault/sensor_fault;
        modbus: mute; drive: a fault code (int, e.g. 0x2310) raises a drive fault with EMCY;
        canopen: heartbeat_loss."""
        if instrument == "drive":
            if fault is None:
                return
            self._require(self.drive, "drive").inject_fault(int(fault))
        elif instrument == "canopen":
            self._require(self.canopen, "CANopen drive").inject(fault)
        else:
            self.server(instrument).inject(fault)

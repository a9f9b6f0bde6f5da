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

import numpy as np
from tcms_daq.sim.instruments.aed import AEDServer
from tcms_daq.sim.instruments.loop import LoopThread
from tcms_daq.sim.instruments.nd287 import ND287Server
from tcms_daq.sim.instruments.physics import SharedPhysics

if TYPE_CHECKING:
    from tcms_daq.sim.instruments.counter import CounterServer
    from tcms_daq.sim.instruments.drive402 import Drive402Model, VelocityDrive402Model
    from tcms_daq.sim.instruments.drive_canopen import DriveCanopenNode
    from tcms_daq.sim.instruments.drive_modbus import DriveModbusServer
    from tcms_daq.sim.instruments.drivetrain import DriveTrainPhysics
    from tcms_daq.sim.instruments.socketcand_hub import SocketcandHub

log = logging.getLogger(__name__)

DEFAULT_PORTS = {"nd287": 4001, "aed": 4002, "modbus": 5020, "socketcand": 29536,
                 "input_aed": 4003, "nd287_coupled": 4004, "counter": 4005}
#: the second axis: the input drive (on the loader's CANopen bus and Modbus server), its torque channel, the ND 287's
#: coupled-axes display and the two-axis counter
SECOND_AXIS = ("input_drive", "input_aed", "nd287_coupled", "counter")
INSTRUMENTS = ("nd287", "aed", "modbus", "modbus_rtu", "canopen", *SECOND_AXIS)


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
    # the second axis (``SECOND_AXIS`` in ``instruments``): the reducer's ratio (None: the catalogue's), the input's
    # friction (Coulomb N·m, viscous N·m per deg/s), the input drive (node id, rated torque, counts per input
    # revolution), the input torque channel's nominal torque, the counter's rate and counts per revolution
    input_ratio: float | None = None
    input_friction_nm: float = 0.5
    input_viscous_nm_per_deg_per_s: float = 0.0
    input_node_id: int = 2
    input_rated_torque_nm: float = 10.0
    input_counts_per_rev: int = 1 << 20
    input_modbus_map: str | None = None  # None = config/modbus-input-drive.toml (unit id 2)
    input_aed_nominal_torque_nm: float = 50.0
    counter_rate_hz: int = 1000
    counter_counts_per_rev_output: int = 18_000 * 4096
    counter_counts_per_rev_input: int = 1 << 23

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


class SecondAxisReadings:
    """What the second axis's simulated sensors read (the counter card, the input AED), at many times at once: the
    output encoder through the bench's measuring chain, the input encoder with its skew and error, the input torque
    with its noise (``[sim.transmission]``)."""

    def __init__(self, sims: InstrumentSimulators):
        self.sims = sims
        config = getattr(sims.physics.bench, "config", None)
        self._noise = np.random.default_rng(int(getattr(getattr(config, "sim", None), "seed", 0)) + 28)

    @property
    def physics(self) -> SharedPhysics:
        return self.sims.physics

    @property
    def drivetrain(self) -> DriveTrainPhysics | None:
        return self.sims.drivetrain

    def output_angles_arcsec(self, time_s: np.ndarray) -> np.ndarray:
        """``InstrumentSimulators.output_angle_arcsec`` at many times. The turning unit's rotation goes through the bench's measuring
        chain with the twist (the output encoder sees the output's whole angle: the chain's scale acts on the
        rotation too, as ``sim.station`` records it); the rigid drivetrain's is added as it is."""
        latest = self.physics.latest()
        t = np.asarray(time_s, dtype=float)
        drivetrain = self.drivetrain
        if drivetrain is None:
            return np.full(t.shape, latest.angle_arcsec)
        state_at = getattr(drivetrain, "state_at", None)
        if state_at is None:
            return latest.angle_arcsec + drivetrain.output_angles_arcsec(t)
        rotation = state_at(t)["output_rotation_arcsec"]
        chain = getattr(self.physics.bench, "measuring_chain", None)
        if chain is None:
            return latest.angle_arcsec + rotation
        true = latest.true_angle_arcsec
        torque = np.full(t.shape, latest.applied_torque_nm)
        through = np.asarray(chain(true + rotation, torque, t), dtype=float) - float(
            np.asarray(chain(np.array([true]), torque[:1], t[:1]), dtype=float)[0])
        return latest.angle_arcsec + through

    def input_angles_deg(self, time_s: np.ndarray) -> np.ndarray:
        """The input encoder's reading (deg) at many times: the shaft latched ``[sim.transmission] sync_skew_s``
        after the output (its angle at t − skew, as ``sim.station`` records it) with its once-per-turn error."""
        t = np.asarray(time_s, dtype=float)
        drivetrain = self.drivetrain
        if drivetrain is None:
            return np.zeros(t.shape)
        state_at = getattr(drivetrain, "state_at", None)
        if state_at is None:
            return drivetrain.input_angles_deg(t)
        tr = self._transmission()
        skew, error = (tr.sync_skew_s, tr.input_encoder_error_arcsec) if tr is not None else (0.0, 0.0)
        angle = state_at(t - skew)["input_angle_deg"]
        return angle + error / 3600.0 * np.sin(np.radians(angle))

    def _transmission(self) -> Any:
        config = getattr(self.physics.bench, "config", None)
        return config.sim.transmission if config is not None else None

    def input_torque_reading_nm(self) -> float:
        """The input torque channel's reading now (N·m): the drivetrain's torque, with ``[sim.transmission]
        input_torque_noise_nm`` of noise when the turning unit is simulated."""
        drivetrain = self.drivetrain
        assert drivetrain is not None
        value = drivetrain.input_torque_nm(self.physics.now_s())
        tr = self._transmission()
        if tr is not None and tr.enabled and tr.input_torque_noise_nm > 0:
            value += tr.input_torque_noise_nm * float(self._noise.standard_normal())
        return value


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
        # the second axis
        self.drivetrain: DriveTrainPhysics | None = None
        self.input_drive: VelocityDrive402Model | None = None
        self.input_canopen: DriveCanopenNode | None = None
        self.input_aed: AEDServer | None = None
        self.nd287_coupled: ND287Server | None = None
        self.counter: CounterServer | None = None
        self.readings = SecondAxisReadings(self)

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
            if want & set(SECOND_AXIS):
                self.drivetrain = self._make_drivetrain()
            if "nd287" in want:
                self.nd287 = ND287Server(
                    self.output_angle_arcsec,
                    host=opts.host,
                    port=opts.ports.get("nd287", 0),
                    unit=opts.nd287_unit,
                    decimals=opts.nd287_decimals,
                    reply_delay_s=opts.nd287_reply_delay_s,
                )
                self.ports["nd287"] = loop.run(self.nd287.start())
            if "aed" in want:
                self.aed = AEDServer(
                    lambda: self.physics.latest().torque_nm, filtered_nm=self.physics.mean_torque_nm,
                    nominal_torque_nm=opts.aed_nominal_torque_nm,
                    host=opts.host,
                    port=opts.ports.get("aed", 0),
                    reply_delay_s=opts.aed_reply_delay_s,
                )
                self.ports["aed"] = loop.run(self.aed.start())
            if want & {"modbus", "modbus_rtu", "canopen"}:
                self._start_drive(want)
            self._start_second_axis(want)
        except BaseException:
            self.stop()
            raise
        return dict(self.ports)

    def _make_drivetrain(self) -> DriveTrainPhysics:
        """The second axis's physics: the core's turning unit when the bench config has ``[sim.transmission]
        enabled`` (``UnitDriveTrain``: its transmission error, mesh loss and friction with breakaway), else a rigid
        reducer with input friction."""
        from tcms_daq.sim.instruments.drivetrain import RigidDriveTrain, UnitDriveTrain

        opts = self.options
        bench = self.physics.bench
        config = getattr(bench, "config", None)
        if config is not None and config.sim.transmission.enabled:
            unit = UnitDriveTrain.for_bench(config, reducer=getattr(bench, "reducer", None))
            assert unit is not None
            if opts.input_ratio is not None and abs(opts.input_ratio - unit.ratio) > 1e-9 * unit.ratio:
                raise ValueError(f"[simulators] input_ratio {opts.input_ratio:g} is not the simulated unit's ratio "
                                 f"{unit.ratio:g} ([sim.transmission] enabled)")
            return unit
        ratio = opts.input_ratio
        if ratio is None:
            reducer = getattr(self.physics.bench, "reducer", None)
            ratio = getattr(reducer, "ratio", None)
        if not ratio:
            raise ValueError("the second axis needs the reducer's ratio: the catalogue entry has none, set "
                             "[simulators] input_ratio")
        return RigidDriveTrain(float(ratio), coulomb_friction_nm=opts.input_friction_nm,
                               viscous_friction_nm_per_deg_per_s=opts.input_viscous_nm_per_deg_per_s)

    def output_angle_arcsec(self, time_s: float | None = None) -> float:
        """What the output encoder reads (arcsec): the bench's reading (twist under the loader, the encoder's errors)
        plus the rotation the second axis drives through the reducer (at ``time_s``, default now)."""
        latest = self.physics.latest()
        if self.drivetrain is None:
            return latest.angle_arcsec
        return float(self.readings.output_angles_arcsec(np.array([latest.time_s if time_s is None else time_s]))[0])

    def input_angle_arcsec(self, time_s: float | None = None) -> float:
        """What the input encoder reads (arcsec of the input shaft)."""
        if self.drivetrain is None:
            return 0.0
        t = self.physics.latest().time_s if time_s is None else time_s
        return self.drivetrain.input_angle_deg(t) * 3600.0

    def _start_second_axis(self, want: set[str]) -> None:
        drivetrain = self.drivetrain
        if drivetrain is None:
            return
        opts, loop = self.options, self.running_loop
        now = self.physics.now_s  # the simulated clock's present (between ticks too)
        if "input_aed" in want:
            self.input_aed = AEDServer(self.readings.input_torque_reading_nm,
                                       nominal_torque_nm=opts.input_aed_nominal_torque_nm, host=opts.host,
                                       port=opts.ports.get("input_aed", 0), reply_delay_s=opts.aed_reply_delay_s)
            self.ports["input_aed"] = loop.run(self.input_aed.start())
        if "nd287_coupled" in want:
            # the display computes X1 − k·X2 from both inputs, k = 1/i as set on it (here: the drivetrain's ratio)
            k = 1.0 / float(getattr(drivetrain, "ratio", opts.input_ratio or 1.0))
            self.nd287_coupled = ND287Server(lambda: self.output_angle_arcsec() - k * self.input_angle_arcsec(),
                                             host=opts.host, port=opts.ports.get("nd287_coupled", 0),
                                             unit=opts.nd287_unit, decimals=opts.nd287_decimals,
                                             reply_delay_s=opts.nd287_reply_delay_s, series="S")
            self.ports["nd287_coupled"] = loop.run(self.nd287_coupled.start())
        if "counter" in want:
            from tcms_daq.sim.instruments.counter import CounterServer

            self.counter = CounterServer(now, self.readings.output_angles_arcsec, self.readings.input_angles_deg,
                                         counts_per_rev_1=opts.counter_counts_per_rev_output,
                                         counts_per_rev_2=opts.counter_counts_per_rev_input,
                                         rate_hz=opts.counter_rate_hz, host=opts.host,
                                         port=opts.ports.get("counter", 0))
            self.ports["counter"] = loop.run(self.counter.start())

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
        more: list[tuple[Drive402Model, Any]] = []
        if "input_drive" in want and self.drivetrain is not None:
            from tcms_daq.sim.instruments.drive402 import VelocityDrive402Model

            self.input_drive = VelocityDrive402Model(
                self.physics, self.drivetrain, counts_per_rev=opts.input_counts_per_rev,
                rated_torque_mnm=round(opts.input_rated_torque_nm * 1000),
                comm_timeout_ms=round(opts.modbus_comm_timeout_s * 1000),
                abort_connection_option=opts.abort_connection_option,
            )
        if "modbus" in want or "modbus_rtu" in want:
            from tcms_daq.sim.instruments.drive_modbus import DriveModbusServer

            from tcms_daq.protocols.modbus_map import (
                INPUT_DRIVE_MAP_PATH,
                VELOCITY_REGISTERS,
                load_register_map,
            )

            regmap = load_register_map(Path(opts.modbus_map) if opts.modbus_map else None)
            if self.input_drive is not None:
                more.append((self.input_drive, load_register_map(
                    Path(opts.input_modbus_map) if opts.input_modbus_map else INPUT_DRIVE_MAP_PATH,
                    VELOCITY_REGISTERS)))
            if "modbus" in want:
                self.modbus = modbus = DriveModbusServer(
                    drive, regmap, host=opts.host, port=opts.ports.get("modbus", 0), more=more,
                )
                self.ports["modbus"] = loop.run(modbus.start())
            if "modbus_rtu" in want:
                self.modbus_rtu = modbus_rtu = DriveModbusServer(
                    drive, regmap, host=opts.host, port=opts.ports.get("modbus_rtu", 0), framer="rtu", more=more,
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
            if self.input_drive is not None:
                from tcms_daq.protocols.cia402 import velocity_drive_eds_path

                self.input_canopen = DriveCanopenNode(
                    self.input_drive, node_id=opts.input_node_id, heartbeat_ms=opts.heartbeat_ms,
                    eds=velocity_drive_eds_path(), **bus_options)
                self.input_canopen.start()

    def stop(self) -> None:
        for node in (self.input_canopen, self.canopen):
            if node is not None:
                node.stop()
        if self.loop is not None:
            for server in (self.nd287, self.aed, self.modbus, self.modbus_rtu, self.input_aed, self.nd287_coupled,
                           self.counter, self.hub):
                if server is not None:
                    try:
                        self.loop.run(server.stop(), 5.0)
                    except Exception as exc:  # noqa: BLE001 - keep stopping the others
                        log.warning("stopping %s: %s", server, exc)
            self.loop.close()
            self.loop = None
        for model in (self.drive, self.input_drive):
            if model is not None:
                model.detach()

    def __enter__(self) -> InstrumentSimulators:
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    # -- control hooks (tests, the control port) -------------------------------------------------------

    def server(self, instrument: str):
        obj = {"nd287": self.nd287, "aed": self.aed, "modbus": self.modbus, "modbus_rtu": self.modbus_rtu,
               "hub": self.hub, "socketcand": self.hub, "input_aed": self.input_aed,
               "nd287_coupled": self.nd287_coupled, "counter": self.counter}.get(instrument)
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
        if instrument == "input_canopen":
            self._require(self.input_canopen, "CANopen input drive").restart()
            return
        self.stop_server(instrument)
        self.start_server(instrument)

    def stop_server(self, instrument: str) -> None:
        """Stop one server; for ``socketcand`` the drive's CAN node goes down with the hub it is attached to."""
        if instrument in ("socketcand", "hub"):
            for node in (self.canopen, self.input_canopen):
                if node is not None:
                    node.stop()
        self.running_loop.run(self.server(instrument).stop())

    def start_server(self, instrument: str) -> None:
        self.running_loop.run(self.server(instrument).start())
        if instrument in ("socketcand", "hub") and self.canopen is not None:
            self._require(self.drive, "drive").power_cycle()
            self.canopen.start()
            if self.input_canopen is not None and self.input_drive is not None:
                self.input_drive.power_cycle()
                self.input_canopen.start()

    def watchdog_reactions(self) -> list[dict[str, float | str]]:
        """What the drive's communication watchdogs did (Modbus timeout, CANopen heartbeat consumer), in order:
        ``{"link", "reaction", "at_monotonic_s", "silent_s"}``."""
        found = [{"link": "modbus", **r} for server in (self.modbus, self.modbus_rtu) if server is not None
                 for r in server.watchdog_reactions]
        for label, node in (("canopen", self.canopen), ("input_canopen", self.input_canopen)):
            if node is not None:
                found += [{"link": label, **r} for r in node.consumer_reactions]
        return sorted(found, key=lambda r: float(r["at_monotonic_s"]))

    def inject(self, instrument: str, fault: str | None) -> None:
        """Fault injection by name: nd287/aed: mute, garbage, partial, encoder_fault/sensor_fault;
        modbus: mute; drive: a fault code (int, e.g. 0x2310) raises a drive fault with EMCY;
        canopen: heartbeat_loss."""
        if instrument == "drive":
            if fault is None:
                return
            self._require(self.drive, "drive").inject_fault(int(fault))
        elif instrument == "input_drive":
            if fault is not None:
                self._require(self.input_drive, "input drive").inject_fault(int(fault))
        elif instrument == "canopen":
            self._require(self.canopen, "CANopen drive").inject(fault)
        elif instrument == "input_canopen":
            self._require(self.input_canopen, "CANopen input drive").inject(fault)
        else:
            self.server(instrument).inject(fault)

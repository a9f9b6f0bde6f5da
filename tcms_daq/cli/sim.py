"""``tcms sim serve``: the simulated instruments of one bench as a standalone process.

ND 287 (TCP, default port 4001), AED (4002), the CiA 402 drive over Modbus TCP (5020) and over CANopen behind a
loopback socketcand hub (29536, channel ``can0``, node id 1) — all on one shared physics (``sim.bench``, the
same bench the in-process run uses, from ``--config``) advanced in real time × ``--speed``. Everything binds
127.0.0.1 unless ``--host`` says otherwise; a port of 0 picks a free one. After start-up one JSON line on
stdout names the ports and the driver URLs; the process runs until SIGINT/SIGTERM (or ``--duration``).

Optional ``[simulators]`` table in the bench config (keys of ``sim.instruments.serve.SimulatorOptions``, e.g.
``rated_torque_nm``, ``aed_nominal_torque_nm``, ``nd287_decimals``, ``[simulators.ports]``); options given on
the command line win. ``--control-port`` opens a loopback control channel for fault injection from tests: one
JSON object per line, ``{"cmd": "inject", "instrument": "nd287", "fault": "encoder_fault"}`` (instruments:
nd287, aed, modbus, socketcand, canopen, drive — a drive fault is an EMCY code such as 8976 = 0x2310),
``{"cmd": "restart", "instrument": "aed"}``, ``{"cmd": "status"}``; each answered by one JSON line.
"""

from __future__ import annotations

import argparse
import json
import signal
import threading
from pathlib import Path
from typing import Any

from tcms_daq.cli.options import add_bench_config_options, write_sim_urls
from tcms_daq.errors import ConfigError, TcmsError


def register(subparsers: argparse._SubParsersAction) -> None:
    sim = subparsers.add_parser("sim", help="simulated instruments speaking the real protocols")
    sim_sub = sim.add_subparsers(dest="sim_command", metavar="SUBCOMMAND")
    serve = sim_sub.add_parser(
        "serve",
        help="run the ND 287, AED, Modbus and CANopen (socketcand) simulators on one shared physics",
        description=__doc__.split("\n\n")[1],
    )
    add_bench_config_options(serve, sim_urls=False)
    serve.add_argument("--host", default=None, help="address to bind (default 127.0.0.1)")
    serve.add_argument("--speed", type=float, default=1.0, help="simulated seconds per real second (default 1)")
    serve.add_argument("--nd287-port", type=int, help="ND 287 TCP port (default 4001; 0 = any free port)")
    serve.add_argument("--aed-port", type=int, help="AED TCP port (default 4002)")
    serve.add_argument("--modbus-port", type=int, help="Modbus TCP port of the drive (default 5020)")
    serve.add_argument("--modbus-rtu-port", type=int,
                       help="also serve Modbus RTU framing over TCP on this port (socket:// URL for the driver)")
    serve.add_argument("--socketcand-port", type=int, help="socketcand hub port (default 29536)")
    serve.add_argument("--input-aed-port", type=int, help="the second axis's input torque AED port (default 4003)")
    serve.add_argument("--nd287-coupled-port", type=int, help="the ND 287 in coupled mode X1 − k·X2 (default 4004)")
    serve.add_argument("--counter-port", type=int, help="the two-axis counter interface (default 4005)")
    serve.add_argument("--second-axis", action="store_true",
                       help="also the second axis: the input drive (CANopen node 2, Modbus unit 2), its AED, the "
                       "ND 287 in coupled mode and the two-axis counter")
    serve.add_argument("--can-channel", help="CAN channel name on the hub (default can0)")
    serve.add_argument("--node-id", type=int, help="CANopen node id of the drive (default 1)")
    serve.add_argument("--control-port", type=int,
                       help="loopback control channel for fault injection (0 = any free port; default off)")
    serve.add_argument("--duration", type=float, help="exit after this many (real) seconds")
    serve.add_argument("--free-ports", action="store_true",
                       help="every server on a free port (ports given on the command line still win)")
    serve.add_argument("--urls-file", metavar="FILE",
                       help="also write the JSON line (ports, URLs by driver) to FILE once listening, removed at exit; "
                       "tcms run/check/serve --sim-urls FILE read it")
    serve.set_defaults(func=_serve)
    sim.set_defaults(func=lambda args: (sim.print_help(), 2)[1])


def _options(args: argparse.Namespace, cfg: Any):
    from tcms_daq.sim.instruments.serve import SimulatorOptions

    table = cfg.simulators.settings()
    ports = dict(table.pop("ports", {}) or {})
    if args.free_ports:
        ports.update(dict.fromkeys(("nd287", "aed", "modbus", "socketcand", "input_aed", "nd287_coupled", "counter"),
                                   0))
    for key, value in (("nd287", args.nd287_port), ("aed", args.aed_port), ("modbus", args.modbus_port),
                       ("socketcand", args.socketcand_port), ("modbus_rtu", args.modbus_rtu_port),
                       ("input_aed", args.input_aed_port), ("nd287_coupled", args.nd287_coupled_port),
                       ("counter", args.counter_port)):
        if value is not None:
            if not 0 <= value <= 65535:
                raise ConfigError(f"--{key.replace('_', '-')}-port must be 0…65535, got {value}")
            ports[key] = value
    instruments = list(table.pop("instruments", ("nd287", "aed", "modbus", "canopen")))
    if args.modbus_rtu_port is not None and "modbus_rtu" not in instruments:
        instruments.append("modbus_rtu")
    if args.second_axis:
        from tcms_daq.sim.instruments.serve import SECOND_AXIS

        instruments += [name for name in SECOND_AXIS if name not in instruments]
    overrides = {"host": args.host, "can_channel": args.can_channel, "node_id": args.node_id}
    try:
        return SimulatorOptions.from_mapping({**table, "ports": ports, "instruments": instruments}, **overrides)
    except ValueError as exc:
        raise ConfigError(f"[simulators]: {exc}") from None


def _urls(opts, ports: dict[str, int]) -> dict[str, str]:
    host = opts.host
    urls = {}
    if "nd287" in ports:
        urls["angle"] = f"socket://{host}:{ports['nd287']}"
    if "aed" in ports:
        urls["torque"] = f"socket://{host}:{ports['aed']}"
    if "modbus" in ports:
        urls["loader_modbus"] = f"tcp://{host}:{ports['modbus']}"
    if "modbus_rtu" in ports:
        urls["loader_modbus_rtu"] = f"socket://{host}:{ports['modbus_rtu']}"
    if "socketcand" in ports:
        urls["loader_canopen"] = f"socketcand://{host}:{ports['socketcand']}/{opts.can_channel}"
    if "input_drive" in opts.instruments:  # the input drive shares the loader's bus and Modbus server
        if "modbus" in ports:
            urls["input_drive_modbus"] = urls["loader_modbus"]
        if "socketcand" in ports:
            urls["input_drive_canopen"] = urls["loader_canopen"]
    for name, key in (("input_aed", "input_torque"), ("nd287_coupled", "input_angle_nd287"),
                      ("counter", "input_angle_counter")):
        if name in ports:
            urls[key] = f"socket://{host}:{ports[name]}"
    return urls


#: the driver (a bench config's instruments.*.driver) each simulator URL serves (tcms … --sim-urls)
DRIVER_URLS = {"nd287": "angle", "aed": "torque", "cia402-canopen": "loader_canopen", "cia402-modbus": "loader_modbus",
               "cia402-velocity-canopen": "input_drive_canopen", "cia402-velocity-modbus": "input_drive_modbus",
               "nd287-coupled": "input_angle_nd287", "counter-2axis": "input_angle_counter",
               "aed@input_torque": "input_torque"}


def _serve(args: argparse.Namespace) -> int:
    from tcms_daq.config import load_bench_config
    from tcms_daq.sim.bench import SimulatedBench
    from tcms_daq.sim.instruments.control import ControlServer
    from tcms_daq.sim.instruments.physics import SharedPhysics
    from tcms_daq.sim.instruments.serve import InstrumentSimulators

    if not args.speed > 0:
        raise ConfigError(f"--speed must be > 0, got {args.speed}")
    cfg = load_bench_config(args.config, args.overrides)
    opts = _options(args, cfg)
    physics = SharedPhysics(SimulatedBench.from_config(cfg))
    sims = InstrumentSimulators(physics, opts)
    stop = threading.Event()
    control = None
    try:
        try:
            ports = sims.start()
        except OSError as exc:
            raise TcmsError(f"cannot start the simulators on {opts.host}: {exc}") from None
        physics.start(speed=args.speed)
        if args.control_port is not None:
            control = ControlServer(sims, host=opts.host, port=args.control_port)
            ports["control"] = sims.running_loop.run(control.start())
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, lambda *_: stop.set())
        urls = _urls(opts, ports)
        info = {"host": opts.host, "ports": ports, "can_channel": opts.can_channel, "node_id": opts.node_id,
                "speed": args.speed, "urls": urls,
                "drivers": {driver: urls[key] for driver, key in DRIVER_URLS.items() if key in urls}}
        if args.urls_file:
            write_sim_urls(Path(args.urls_file), info)
        print(json.dumps(info), flush=True)
        stop.wait(args.duration)
    finally:
        if args.urls_file:
            Path(args.urls_file).unlink(missing_ok=True)
        if control is not None:
            sims.running_loop.run(control.stop())
        physics.stop()
        sims.stop()
    return 0

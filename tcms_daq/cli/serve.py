"""``tcms serve``: the FastAPI service with the dashboard, REST API, live WebSockets and the run store."""

from __future__ import annotations

import argparse
import gc
import math
from pathlib import Path

from tcms_daq.cli.options import add_bench_config_options
from tcms_daq.errors import ConfigError, TcmsError
from tcms_daq.settings import DEFAULT_DATA_DIR, read_settings


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "serve",
        help="run the web service (dashboard, REST API, live data)",
        description="Start the TCMS-DAQ service. Default: the simulated bench in-process and a SQLite (WAL) "
        "run store in the data directory. Mutating endpoints need 'Authorization: Bearer <token>'; the token "
        "comes from the config ([service] api_token), TCMS_API_TOKEN, or is generated and printed.",
    )
    add_bench_config_options(p)
    p.add_argument("--host", default="127.0.0.1", help="interface to bind (default 127.0.0.1)")
    p.add_argument("--port", type=int, default=8000, help="TCP port (default 8000; 0 = any free port)")
    p.add_argument("--data-dir", type=Path, default=None,
                   help=f"run store directory (default: $TCMS_DATA_DIR or ./{DEFAULT_DATA_DIR}); the SQLite store "
                        "and the discrepancy analyses live here")
    p.add_argument("--store", metavar="URL", default=None,
                   help="run store: postgresql://user@host:port/db (a plant's benches share one database) or "
                        "sqlite:///path (default: $TCMS_STORE_URL, else the config's [store] url, else the SQLite "
                        "file in the data directory)")
    p.add_argument("--opcua-port", type=int, default=None, metavar="N",
                   help="serve the bench as an OPC UA machine (OPC 40001-1) with its results (OPC 40001-101) on port "
                        "N (0 = any free port; default: the config's [opcua] port, else off); security and users "
                        "from [opcua]")
    p.add_argument("--opcua-host", default=None, metavar="ADDRESS",
                   help="interface the OPC UA server binds (default: [opcua] host, 127.0.0.1)")
    p.add_argument("--sim-speed", type=float, default=1.0,
                   help="simulated seconds per real second for a simulated bench (default 1 = real time)")
    p.add_argument("--read-token", choices=["auto", "on", "off"], default="auto",
                   help="reads (/api/…, /ws/…, /metrics) need the token too: 'auto' (default) when bound beyond "
                        "loopback, 'on' always, 'off' never (liveness, the dashboard's files and /docs stay open)")
    p.add_argument("--log-level", default="warning", choices=["critical", "error", "warning", "info", "debug"])
    p.set_defaults(func=run)


def _loopback(host: str) -> bool:
    import ipaddress

    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False  # a host name: assume it is reachable from elsewhere


def _service_token(config) -> str | None:
    """``[service] api_token`` of the loaded bench config, if present."""
    return config.service.api_token


def run(args: argparse.Namespace) -> int:
    import socket

    import uvicorn

    from tcms_daq.service.app import ServiceSettings, create_app
    from tcms_daq.service.auth import redact_tokens_in_logs
    from tcms_daq.service.runner import BenchRunner
    from tcms_daq.store.opening import store_kind

    if not (args.sim_speed > 0 and math.isfinite(args.sim_speed)):
        raise ConfigError(f"--sim-speed must be a positive number, got {args.sim_speed}")
    if not 0 <= args.port <= 65535:
        raise ConfigError(f"--port must be 0…65535, got {args.port}")
    if args.opcua_port is not None and not 0 <= args.opcua_port <= 65535:
        raise ConfigError(f"--opcua-port must be 0…65535, got {args.opcua_port}")
    env = read_settings()
    data_dir = Path(args.data_dir or env.data_dir)
    # Compose the bench and reach its instruments before the server starts, so a bad config or an instrument
    # that does not answer is a one-line error, not a startup traceback after the URL was printed.
    runner = BenchRunner.from_config(args.config, sim_speed=args.sim_speed, overrides=args.overrides)
    store_url = args.store or env.store_url or runner.config.store.url
    try:
        store_kind(store_url)
    except TcmsError as exc:
        raise ConfigError(str(exc)) from None
    opcua = runner.config.opcua
    if args.opcua_host:
        opcua = opcua.model_copy(update={"host": args.opcua_host})
    opcua_port = args.opcua_port if args.opcua_port is not None else opcua.port
    if opcua_port is not None:
        from tcms_daq.service.opcua import OpcUaError, check_config

        try:
            check_config(opcua, data_dir)
        except OpcUaError as exc:
            raise ConfigError(str(exc)) from None
        if opcua_port:
            _check_port_free(opcua.host, opcua_port)
    store = _open_store(store_url, data_dir, runner)
    everywhere = args.host in ("0.0.0.0", "::", "")
    settings = ServiceSettings(
        data_dir=data_dir, config_path=args.config, store_url=store_url, sim_speed=args.sim_speed,
        opcua_port=opcua_port, opcua=opcua, api_token=_service_token(runner.config),
        # Host check against DNS rebinding on loopback; bound to all interfaces the names are not known here
        allowed_hosts=None if everywhere else ("127.0.0.1", "localhost", "::1", "[::1]", args.host),
        read_token_required=args.read_token == "on" or (args.read_token == "auto" and not _loopback(args.host)),
    )
    sock = socket.socket(socket.AF_INET6 if ":" in args.host else socket.AF_INET, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((args.host, args.port))
    except OSError as exc:
        sock.close()
        store.close()
        raise ConfigError(f"cannot listen on {args.host}:{args.port} ({exc.strerror})") from None
    try:
        runner.bench.connect()
    except BaseException:
        sock.close()
        store.close()
        raise
    app = create_app(settings, runner=runner, store=store)
    sock.listen(2048)  # connections made from now on wait in the backlog until the app is ready
    _print_banner(args, app, runner, sock.getsockname()[1], store)
    config = uvicorn.Config(app, log_level=args.log_level, ws_per_message_deflate=False, lifespan="on",
                            timeout_graceful_shutdown=10)
    redact_tokens_in_logs()  # after uvicorn configured its loggers and handlers
    server = _server(config)
    # the start-up's objects (modules, the app, the bench: some 10^5) leave the collector's generations, so a request
    # that allocates many (SPC's 10 000 runs) no longer traverses them at each full collection (its CPU halved)
    gc.freeze()
    server.run(sockets=[sock])  # after a signal, uvicorn re-raises it here: the process ends with its status
    if not server.started:
        print("TCMS-DAQ service did not start (see the error above).", flush=True)
    return 0 if server.started else 1


def _check_port_free(host: str, port: int) -> None:
    """The OPC UA port can be bound on ``host`` (one-line error otherwise)."""
    import socket

    with socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET) as probe:
        try:
            probe.bind((host, port))
        except OSError as exc:
            raise ConfigError(f"OPC UA port {port}: cannot listen on {host}:{port} ({exc.strerror})") from None


def _open_store(url: str | None, data_dir: Path, runner):
    """The bench's run store, opened as the service will use it (its runs left active by a dead service are
    marked interrupted); a one-line error when it cannot be opened."""
    import sqlite3

    from tcms_daq.service.app import bench_identity
    from tcms_daq.store import StoreError, open_store

    bench_id, bench_name = bench_identity(runner)
    try:
        data_dir.mkdir(parents=True, exist_ok=True)
        return open_store(url, data_dir, bench_id=bench_id, bench_name=bench_name)
    except StoreError as exc:
        raise ConfigError(str(exc)) from None
    except (OSError, sqlite3.Error) as exc:
        reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
        from tcms_daq.store.opening import sqlite_path

        raise ConfigError(f"run store {sqlite_path(url, data_dir)}: cannot open it ({reason}); choose another "
                          "--data-dir") from None


def _server(config):
    """uvicorn's server, saying so when a signal (Ctrl+C, SIGTERM) starts the shutdown."""
    import uvicorn

    class Server(uvicorn.Server):
        def handle_exit(self, sig, frame) -> None:
            if not self.should_exit:
                print("TCMS-DAQ service stopping: an active test is aborted, the bench ramps down …", flush=True)
            super().handle_exit(sig, frame)

    return Server(config)


def _print_banner(args: argparse.Namespace, app, runner, port: int, store) -> None:
    """What a test engineer needs: the dashboard URL with the token, the token for scripts, the bench."""
    host = "127.0.0.1" if args.host in ("0.0.0.0", "::") else args.host
    host = f"[{host}]" if ":" in host else host
    base = f"http://{host}:{port}"
    token = app.state.api_token
    where = {"generated": "generated for this session", "environment": "from TCMS_API_TOKEN",
             "config": f"from {runner.config_path} [service] api_token"}[app.state.api_token_source]
    status = runner.status()
    clock = (f"simulated clock at {args.sim_speed:g}× real time" if status["clock"] == "simulated"
             else "real-time clock")
    listening = f" (listening on {args.host})" if args.host in ("0.0.0.0", "::") else ""
    print(f"TCMS-DAQ service on {base}/{listening}")
    print(f"  Dashboard:  {base}/?token={token}    <- open this in a browser")
    print(f"  API token:  {token}  ({where}; scripts send 'Authorization: Bearer <token>')")
    print(f"  API docs:   {base}/docs")
    print(f"  Bench:      {status['name']} ({status['config']}), {clock}")
    print(f"  Run store:  {store.describe()} (bench id {store.bench_id})")
    print("  Stop with Ctrl+C (an active test is aborted and the bench ramps down).", flush=True)

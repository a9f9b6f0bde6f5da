"""``tcms serve``: the FastAPI service with the dashboard, REST API, live WebSockets and the run store."""

from __future__ import annotations

import argparse
import logging
import math
from pathlib import Path

from tcms_daq.cli.options import add_bench_config_options
from tcms_daq.errors import ConfigError
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
                   help=f"run store directory (default: $TCMS_DATA_DIR or ./{DEFAULT_DATA_DIR})")
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
    token = ((config.model_extra or {}).get("service") or {}).get("api_token")
    return str(token) if token else None


def run(args: argparse.Namespace) -> int:
    import socket

    import uvicorn

    from tcms_daq.service.app import ServiceSettings, create_app
    from tcms_daq.service.auth import RedactTokenInAccessLog
    from tcms_daq.service.runner import BenchRunner
    from tcms_daq.store import STORE_FILENAME

    if not (args.sim_speed > 0 and math.isfinite(args.sim_speed)):
        raise ConfigError(f"--sim-speed must be a positive number, got {args.sim_speed}")
    if not 0 <= args.port <= 65535:
        raise ConfigError(f"--port must be 0…65535, got {args.port}")
    data_dir = args.data_dir or read_settings().data_dir
    _check_store(Path(data_dir) / STORE_FILENAME)
    # Compose the bench and reach its instruments before the server starts, so a bad config or an instrument
    # that does not answer is a one-line error, not a startup traceback after the URL was printed.
    runner = BenchRunner.from_config(args.config, sim_speed=args.sim_speed, overrides=args.overrides)
    everywhere = args.host in ("0.0.0.0", "::", "")
    settings = ServiceSettings(
        data_dir=data_dir, config_path=args.config, sim_speed=args.sim_speed, api_token=_service_token(runner.config),
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
        raise ConfigError(f"cannot listen on {args.host}:{args.port} ({exc.strerror})") from None
    try:
        runner.bench.connect()
    except BaseException:
        sock.close()
        raise
    app = create_app(settings, runner=runner)
    sock.listen(2048)  # connections made from now on wait in the backlog until the app is ready
    _print_banner(args, app, runner, sock.getsockname()[1], Path(data_dir) / STORE_FILENAME)
    config = uvicorn.Config(app, log_level=args.log_level, ws_per_message_deflate=False, lifespan="on",
                            timeout_graceful_shutdown=10)
    logging.getLogger("uvicorn.access").addFilter(RedactTokenInAccessLog())
    server = _server(config)
    server.run(sockets=[sock])  # after a signal, uvicorn re-raises it here: the process ends with its status
    if not server.started:
        print("TCMS-DAQ service did not start (see the error above).", flush=True)
    return 0 if server.started else 1


def _check_store(path: Path) -> None:
    """The run store can be created or opened (one-line error otherwise; runs are left as they are)."""
    import sqlite3

    from tcms_daq.store import RunStore

    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        RunStore(path, recover=False).close()
    except (OSError, sqlite3.Error) as exc:
        reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
        raise ConfigError(f"run store {path}: cannot open it ({reason}); choose another --data-dir") from None


def _server(config):
    """uvicorn's server, saying so when a signal (Ctrl+C, SIGTERM) starts the shutdown."""
    import uvicorn

    class Server(uvicorn.Server):
        def handle_exit(self, sig, frame) -> None:
            if not self.should_exit:
                print("TCMS-DAQ service stopping: an active test is aborted, the bench ramps down …", flush=True)
            super().handle_exit(sig, frame)

    return Server(config)


def _print_banner(args: argparse.Namespace, app, runner, port: int, store_path: Path) -> None:
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
    print(f"  Run store:  {store_path.resolve()}")
    print("  Stop with Ctrl+C (an active test is aborted and the bench ramps down).", flush=True)

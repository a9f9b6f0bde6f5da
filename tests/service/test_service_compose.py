"""docker-compose.yml, the Dockerfile and config/bench-compose.toml agree with each other and with the CLI.

No Docker engine is needed: the compose file is parsed (PyYAML, installed with uvicorn[standard]) and its
commands are parsed by the real ``tcms`` argument parser.
"""

from __future__ import annotations

from pathlib import Path
from urllib.parse import urlparse

import yaml

from tcms_daq.cli import build_parser
from tcms_daq.config import load_bench_config, packaged_config_dir, resolve_config_path

REPO = Path(__file__).resolve().parents[2]


def _compose() -> dict:
    return yaml.safe_load((REPO / "docker-compose.yml").read_text(encoding="utf-8"))


def _published(service: dict) -> dict[int, int]:
    out = {}
    for spec in service["ports"]:
        host, container = str(spec).split(":")
        out[int(container)] = int(host)
    return out


def test_compose_services_commands_ports_and_healthchecks():
    compose = _compose()
    services = compose["services"]
    assert set(services) == {"postgres", "sim", "tcms", "sim-2", "tcms-2"}
    sim, tcms = services["sim"], services["tcms"]
    for svc in (sim, tcms, services["sim-2"], services["tcms-2"]):
        assert svc["build"] == "."
        check = svc["healthcheck"]
        assert check["test"][0] == "CMD" and check["interval"] and check["retries"] >= 3

    assert sim["command"][:3] == ["tcms", "sim", "serve"]
    assert sim["command"][sim["command"].index("--host") + 1] == "0.0.0.0"
    assert tcms["command"][:2] == ["tcms", "serve"]
    cmd = tcms["command"]
    assert cmd[cmd.index("--config") + 1] == "bench-compose.toml"  # a packaged config, found by name
    assert resolve_config_path("bench-compose.toml") == packaged_config_dir() / "bench-compose.toml"
    assert cmd[cmd.index("--host") + 1] == "0.0.0.0"
    port = int(cmd[cmd.index("--port") + 1])
    assert _published(tcms)[port] == port
    assert "/api/health" in " ".join(tcms["healthcheck"]["test"]) and str(port) in " ".join(tcms["healthcheck"]["test"])
    assert tcms["depends_on"]["sim"]["condition"] == "service_healthy"
    data_dir = cmd[cmd.index("--data-dir") + 1]
    assert any(v.endswith(":" + data_dir) for v in tcms["volumes"])

    # the service's command line is accepted by `tcms serve` itself
    args = build_parser().parse_args(cmd[1:])
    assert args.command == "serve" and args.host == "0.0.0.0" and args.port == port


def test_compose_bench_points_at_the_sim_service_on_published_ports():
    compose = _compose()
    sim_ports = _published(compose["services"]["sim"])
    cfg = load_bench_config(REPO / "config" / "bench-compose.toml")
    for kind in ("angle", "torque", "loader"):
        url = urlparse(getattr(cfg.instruments, kind).url)
        assert url.hostname == "sim", f"{kind} must talk to the compose service 'sim'"
        assert url.port in sim_ports, f"{kind} port {url.port} is not published by the sim service"
    from tcms_daq.sim.instruments.serve import DEFAULT_PORTS

    assert {DEFAULT_PORTS["nd287"], DEFAULT_PORTS["aed"], DEFAULT_PORTS["socketcand"]} <= set(sim_ports)
    sim_check = " ".join(compose["services"]["sim"]["healthcheck"]["test"])
    for p in (DEFAULT_PORTS["nd287"], DEFAULT_PORTS["aed"], DEFAULT_PORTS["socketcand"]):
        assert str(p) in sim_check
    # the compensation file the config names is in the image's config directory
    assert (REPO / "config" / cfg.bench.compensation).is_file()


def test_sim_command_is_a_tcms_command():
    cmd = _compose()["services"]["sim"]["command"]
    args = build_parser().parse_args(cmd[1:])
    assert args.command == "sim"


def test_dockerfile_installs_the_package_and_runs_the_service():
    text = (REPO / "Dockerfile").read_text(encoding="utf-8")
    lines = [ln.strip() for ln in text.splitlines() if ln.strip() and not ln.strip().startswith("#")]
    assert lines[0].startswith("FROM python:3.11")
    for src in ("tcms_daq", "drivers", "sim", "config", "pyproject.toml"):  # config/: tcms_daq.defaults
        assert any(ln.startswith("COPY") and src in ln for ln in lines), src
    assert any("pip install" in ln and "[plant]" in ln for ln in lines), "the plant's store needs the [plant] extra"
    assert "TCMS_DATA_DIR=/data" in text
    assert any(ln.startswith("EXPOSE 8000") for ln in lines)
    assert lines[-1].startswith('CMD ["tcms", "serve"')


def _bench_of(service: dict):
    """The bench config a compose `tcms serve` service runs: its --config with its --set overrides."""
    args = build_parser().parse_args(service["command"][1:])
    return args, load_bench_config(args.config, args.overrides)


def test_two_benches_share_the_postgres_service_with_their_own_instruments_and_ids():
    services = _compose()["services"]
    pg = services["postgres"]
    assert pg["image"].startswith("postgres:") and "pg_isready" in pg["healthcheck"]["test"]
    user, db = pg["environment"]["POSTGRES_USER"], pg["environment"]["POSTGRES_DB"]
    assert any(v.endswith(":/var/lib/postgresql/data") for v in pg["volumes"])
    ids, ports = set(), set()
    for name, sim_name in (("tcms", "sim"), ("tcms-2", "sim-2")):
        svc = services[name]
        url = urlparse(svc["environment"]["TCMS_STORE_URL"].replace("${TCMS_DB_PASSWORD:-tcms}", "pw"))
        assert url.scheme == "postgresql" and url.hostname == "postgres" and url.port == 5432
        assert url.username == user and url.path == f"/{db}"
        assert svc["depends_on"]["postgres"]["condition"] == "service_healthy"
        assert svc["depends_on"][sim_name]["condition"] == "service_healthy"
        args, cfg = _bench_of(svc)
        assert args.store is None  # the URL comes from TCMS_STORE_URL
        for kind in ("angle", "torque", "loader"):
            assert urlparse(getattr(cfg.instruments, kind).url).hostname == sim_name, (name, kind)
        ids.add(cfg.bench.bench_id)
        ports.add(args.port)
        assert _published(svc)[args.port] == args.port and str(args.port) in " ".join(svc["healthcheck"]["test"])
        data_dir = args.data_dir
        assert any(v.endswith(":" + str(data_dir)) for v in svc["volumes"])
    assert ids == {"compose-1", "compose-2"} and len(ports) == 2  # each bench its own id: no run of the other
    # is ever marked interrupted by its restart
    sim2 = build_parser().parse_args(services["sim-2"]["command"][1:])
    assert sim2.command == "sim" and "ports" not in services["sim-2"]  # the second bench's instruments stay inside
    assert load_bench_config(sim2.config, sim2.overrides).sim.seed == 2

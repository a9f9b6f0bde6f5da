"""``tcms check`` against ``tcms sim serve`` in another process (ephemeral ports): every instrument answers and
nothing moves; an instrument that is down is named and the exit code is 1."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
from tcms_daq.sim.instruments.child import running_simulators


@pytest.fixture(scope="module")
def served():
    with running_simulators("--config", "bench-loopback.toml", "--speed", "1") as info:
        yield info


def _check(config: str, urls: dict[str, str]) -> tuple[int, dict]:
    sets = [arg for kind, url in urls.items() for arg in ("--set", f"instruments.{kind}.url={url}")]
    done = subprocess.run([sys.executable, "-m", "tcms_daq.cli", "check", "--config", config, *sets, "--json",
                           "--duration", "0.5"], capture_output=True, text=True, timeout=90)
    return done.returncode, json.loads(done.stdout)


@pytest.mark.parametrize(("config", "loader"), [("bench-loopback.toml", "loader_canopen"),
                                                ("bench-loopback-modbus.toml", "loader_modbus")])
def test_check_finds_every_instrument(served, config, loader):
    urls = {"angle": served["urls"]["angle"], "torque": served["urls"]["torque"], "loader": served["urls"][loader]}
    code, report = _check(config, urls)
    assert code == 0 and report["ok"] and report["down"] == [], report
    by_kind = {e["kind"]: e for e in report["instruments"]}
    for kind in ("angle", "torque"):
        assert by_kind[kind]["ok"] and by_kind[kind]["readings"] > 5 and by_kind[kind]["rate_per_s"] > 5
    drive = by_kind["loader"]
    assert drive["ok"] and drive["state"] == "SWITCH ON DISABLED"  # read, never enabled
    assert drive["rated_torque_nm"] == pytest.approx(2000.0) and drive["can_move"] is True
    assert drive["position_deg"] == pytest.approx(0.0, abs=0.1)  # nothing moved
    assert abs(drive["torque_actual_nm"]) < 5.0


def test_check_names_the_instrument_that_is_down(served, tmp_path):
    import socket

    with socket.socket() as closed:  # a port nothing listens on
        closed.bind(("127.0.0.1", 0))
        dead = closed.getsockname()[1]
    urls = {"angle": served["urls"]["angle"], "torque": f"socket://127.0.0.1:{dead}",
            "loader": served["urls"]["loader_canopen"]}
    code, report = _check("bench-loopback.toml", urls)
    assert code == 1 and report["down"] == ["torque"]
    torque = next(e for e in report["instruments"] if e["kind"] == "torque")
    assert not torque["ok"] and "AED" in torque["error"] and str(dead) in torque["error"]
    assert all(e["ok"] for e in report["instruments"] if e["kind"] != "torque")
    # the table names it too
    sets = [a for k, u in urls.items() for a in ("--set", f"instruments.{k}.url={u}")]
    done = subprocess.run([sys.executable, "-m", "tcms_daq.cli", "check", "--config", "bench-loopback.toml", *sets,
                           "--duration", "0.3"], capture_output=True, text=True, timeout=90)
    assert done.returncode == 1 and "DOWN" in done.stdout and "down: torque (AED)" in done.stdout


@pytest.mark.parametrize(("config", "loader_class"), [("bench-hardware-canopen.toml", "CiA402Canopen"),
                                                      ("bench-hardware-modbus.toml", "CiA402Modbus")])
def test_packaged_hardware_examples_compose(config, loader_class):
    """docs/hardware.md's example configs load and build their drivers with the documented settings (nothing is
    opened: that is tcms check's job on the bench)."""
    from pathlib import Path

    from tcms_daq.acquisition import compose_bench
    from tcms_daq.config import load_bench_config

    cfg = load_bench_config(config)
    bench = compose_bench(cfg, config_dir=Path(cfg.source_path).parent)
    assert type(bench.loader).__name__ == loader_class
    assert bench.loader.counts_per_rev == 1 << 20 and bench.loader.max_torque_nm == 1100.0
    assert bench.angle.name == "ND 287" and bench.torque.name == "AED"
    assert bench.description["angle"]["baudrate"] == 115200 and bench.description["torque"]["baudrate"] == 38400
    # the drive's own watchdog, from the typed [instruments.loader] fields, to the driver that takes each
    if loader_class == "CiA402Modbus":
        assert bench.loader.comm_timeout_ms == 1000 and bench.loader.abort_connection_option == 1
    else:
        assert bench.loader.master_heartbeat_ms == 100 and bench.loader.drive_consumer_timeout_ms == 1000

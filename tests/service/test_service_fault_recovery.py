"""The fault table on the real-time protocol bench (issue 10): `tcms sim serve` in one process, `tcms serve` over
the protocols in another. For each fault the simulators can inject mid-test: the test ends aborted with the
reason, the drive is left disabled, the fault is cleared, and the next test completes — no restart."""

from __future__ import annotations

import json
import socket
import subprocess
import sys
import time

import httpx
import pytest
from svc_helpers import TOKEN, start_serve_process, stop_process, wait_for

REQUEST = {"reducer": "RV-110E", "max_torque_nm": 400, "cycles": 1, "rate_nm_per_s": 400}
FAULT_AFTER_S = 1.0  # real seconds into the test (speed 4: well inside the loading)

# (instrument, fault, what the abort reason names)
FAULTS = [
    ("nd287", "encoder_fault", "angle instrument fault"),
    ("nd287", "garbage", "lost angle instrument"),
    ("nd287", "mute", "angle"),
    ("aed", "garbage", "lost torque instrument"),
    ("aed", "sensor_fault", "torque instrument fault"),
    ("aed", "mute", "torque"),
    ("drive", 0x2310, "drive fault 0x2310"),
    ("canopen", "heartbeat_loss", "loader"),
]


def _control(port: int, **request) -> dict:
    with socket.create_connection(("127.0.0.1", port), timeout=5) as sock:
        sock.sendall((json.dumps(request) + "\n").encode())
        return json.loads(sock.makefile().readline())


@pytest.fixture(scope="module")
def bench(tmp_path_factory):
    sim = subprocess.Popen([sys.executable, "-m", "tcms_daq.cli", "sim", "serve", "--config", "bench-loopback.toml",
                            "--nd287-port", "0", "--aed-port", "0", "--modbus-port", "0", "--socketcand-port", "0",
                            "--control-port", "0", "--speed", "4"],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    service = None
    try:
        info = json.loads(sim.stdout.readline() or "{}")
        assert "urls" in info, sim.stderr.read()
        urls = info["urls"]
        service, base = start_serve_process([
            "--config", "bench-loopback.toml", "--port", "0", "--sim-speed", "4",
            "--data-dir", str(tmp_path_factory.mktemp("data")),
            "--set", f"instruments.angle.url={urls['angle']}", "--set", f"instruments.torque.url={urls['torque']}",
            "--set", f"instruments.loader.url={urls['loader_canopen']}"])
        client = httpx.Client(base_url=base, headers={"Authorization": f"Bearer {TOKEN}"}, timeout=20)
        wait_for(lambda: client.get("/api/health").status_code == 200, timeout_s=30)
        yield client, info["ports"]["control"]
        client.close()
    finally:
        if service is not None:
            stop_process(service)
        sim.terminate()
        sim.wait(15)


def _run(client: httpx.Client, on_the_way=None) -> dict:
    r = client.post("/api/tests", json=REQUEST)
    assert r.status_code == 202, r.text
    run_id, started, done = r.json()["id"], time.monotonic(), False
    while True:
        run = client.get(f"/api/tests/{run_id}").json()
        if run["status"] in ("completed", "failed", "aborted"):
            return run
        if on_the_way is not None and not done and time.monotonic() - started > FAULT_AFTER_S:
            on_the_way()
            done = True
        assert time.monotonic() - started < 120, run
        time.sleep(0.1)


@pytest.mark.slow
@pytest.mark.timeout(600)
@pytest.mark.parametrize("instrument, fault, reason", FAULTS, ids=[f"{i}-{f}" for i, f, _ in FAULTS])
def test_fault_aborts_safely_and_the_next_test_completes(bench, instrument, fault, reason):
    client, control = bench
    aborted = _run(client, lambda: _control(control, cmd="inject", instrument=instrument, fault=fault))
    assert aborted["status"] == "aborted", aborted
    assert reason in aborted["error"], aborted["error"]
    _control(control, cmd="inject", instrument=instrument, fault=None)
    # the physics behind the simulators: the drive left disabled at (nearly) zero torque
    state = wait_for(lambda: (s := _control(control, cmd="status"))["drive"]["state"] != "OPERATION ENABLED"
                     and abs(s["applied_torque_nm"]) < 20.0 and s, timeout_s=30)
    assert state["drive"]["state"] in ("SWITCH ON DISABLED", "FAULT", "READY TO SWITCH ON"), state
    after = _run(client)
    assert after["status"] == "completed", after["error"]
    assert 250 < after["results"]["rigidity_nm_per_arcmin"] < 350

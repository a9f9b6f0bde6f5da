"""The drive stops by itself (issue 22), on the real-time protocol bench: `tcms sim serve` in one process, `tcms serve`
over its protocols in another, the loader over CANopen or Modbus TCP. A test loads the reducer; at |torque| >= 600 N·m
the service is killed (SIGKILL: nothing of it runs any more) or the loader's link goes mute (the simulators' control
channel). The drive's own communication watchdog — armed by the driver on connect, fed while it lives — must stop
the drive: disabled or in fault, |torque| < 20 N·m, within 2 s of the kill or mute (the time is the simulator's own
record of its watchdog's reaction, on the system-wide monotonic clock, not this test's polling). A restarted service
reports what its safe start found and the next test completes. Without a drive watchdog (configured off), the
restarted service's safe start is what brings the drive from full torque to a safe state."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
import tomllib
from pathlib import Path

import httpx
import pytest
import tomli_w
from svc_helpers import (
    TOKEN,
    completes_on_a_loaded_bench,
    loopback_config_with_loader,
    stop_process,
    wait_for,
)
from tcms_daq.sim.instruments.child import start_simulators

from tcms_daq.config.loader import resolve_config_path

SPEED = 4.0  # simulated seconds per real second (the watchdogs count real time)
LOAD = {"reducer": "RV-110E", "max_torque_nm": 800, "cycles": 1, "rate_nm_per_s": 200}
# the test after the restart runs two loops: a stall of the loaded real-time bench leaves a gap that the run rightly
# refuses to evaluate across (CI: 0.29 s without readings in a one-loop run, which then failed)
NEXT = {"reducer": "RV-110E", "max_torque_nm": 400, "cycles": 2, "rate_nm_per_s": 400}
TRIGGER_TORQUE_NM = 600.0
SAFE_TORQUE_NM = 20.0
STOP_BOUND_S = 2.0  # issue 22: the drive disabled or in fault, |torque| < 20 N·m, within 2 s
STARTUP_CEILING_S = 180.0  # a process's readiness on a loaded 2-core machine (a ceiling, not an expectation)
POWERED = ("OPERATION ENABLED", "SWITCHED ON", "QUICK STOP ACTIVE")


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


class ProtocolBench:
    """The simulators (own process) and the service (own process, restartable) on loopback."""

    def __init__(self, data_dir: Path, loader: str, *, watchdog: bool = True):
        self.data_dir, self.loader = data_dir, loader
        self.ports = {name: _free_port() for name in ("nd287", "aed", "modbus", "socketcand", "control")}
        sim_config = data_dir / "sim.toml"
        packaged = resolve_config_path("bench-loopback.toml")
        cfg = tomllib.loads(packaged.read_text(encoding="utf-8"))
        cfg["sim"]["geometry"] = str(packaged.parent / cfg["sim"]["geometry"])
        cfg["bench"]["compensation"] = str(packaged.parent / cfg["bench"]["compensation"])
        cfg["bench"]["reducers"] = str(packaged.parent / cfg["bench"]["reducers"])
        if not watchdog:
            cfg["simulators"] = {"modbus_comm_timeout_s": 0.0}
        sim_config.write_text(tomli_w.dumps(cfg), encoding="utf-8")
        self.sim, info = start_simulators("--config", str(sim_config), "--speed", str(SPEED), ports=self.ports,
                                          timeout_s=STARTUP_CEILING_S)
        self.urls = info["urls"]
        # watchdog=False: the drive's communication watchdog off on both sides (driver and the simulated drive)
        self.config = loopback_config_with_loader(data_dir / f"bench-{loader}-{'wd' if watchdog else 'nowd'}.toml",
                                                  loader, self.urls, **({} if watchdog else {"comm_timeout_ms": 0}))
        self.service: subprocess.Popen | None = None
        self.output: list[str] = []
        self.client: httpx.Client | None = None
        self.start_service()

    def start_service(self) -> None:
        """``tcms serve`` (as svc_helpers.start_serve_process starts it), keeping every line it prints: the safe
        start's log line comes before the banner."""
        env = {**os.environ, "TCMS_API_TOKEN": TOKEN, "PYTHONUNBUFFERED": "1"}
        self.service = proc = subprocess.Popen([
            sys.executable, "-m", "tcms_daq.cli", "serve", "--config", str(self.config), "--port", "0",
            "--sim-speed", str(SPEED), "--data-dir", str(self.data_dir),
            "--set", f"instruments.angle.url={self.urls['angle']}",
            "--set", f"instruments.torque.url={self.urls['torque']}"],
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
        self.output = []
        started = threading.Event()
        threading.Thread(target=self._drain, args=(proc, self.output, started), daemon=True).start()
        if not started.wait(STARTUP_CEILING_S):
            stop_process(proc)
            raise AssertionError(f"tcms serve did not start: {''.join(self.output)!r}")
        line = next(x for x in self.output if "service on http://" in x)
        base = "http://" + line.split("http://", 1)[1].split("/", 1)[0]
        if self.client is not None:
            self.client.close()
        self.client = httpx.Client(base_url=base, headers={"Authorization": f"Bearer {TOKEN}"}, timeout=30)
        wait_for(lambda: self.client.get("/api/health").status_code == 200, timeout_s=STARTUP_CEILING_S)

    @staticmethod
    def _drain(proc: subprocess.Popen, lines: list[str], started: threading.Event) -> None:
        """Read the service's output (its log lines) so its pipe never fills; ``started`` once it printed its URL
        (or ended)."""
        assert proc.stdout is not None
        for line in proc.stdout:
            lines.append(line)
            if "service on http://" in line:
                started.set()
        started.set()

    def kill_service(self) -> float:
        """SIGKILL the service; time.monotonic() just before."""
        assert self.service is not None
        at = time.monotonic()
        os.kill(self.service.pid, signal.SIGKILL)
        self.service.wait(30)
        return at

    def control(self, **request) -> dict:
        with socket.create_connection(("127.0.0.1", self.ports["control"]), timeout=30) as sock:
            sock.sendall((json.dumps(request) + "\n").encode())
            reply = json.loads(sock.makefile().readline())
        assert reply.get("ok", True), reply
        return reply

    def close(self) -> None:
        if self.client is not None:
            self.client.close()
        if self.service is not None:
            stop_process(self.service)
        stop_process(self.sim)


@pytest.fixture
def protocol_bench(tmp_path):
    made: list[ProtocolBench] = []

    def make(loader: str, **kw) -> ProtocolBench:
        made.append(ProtocolBench(tmp_path, loader, **kw))
        return made[-1]

    yield make
    for bench in made:
        bench.close()


def _post(bench: ProtocolBench, request: dict) -> str:
    assert bench.client is not None
    r = bench.client.post("/api/tests", json=request)
    assert r.status_code == 202, r.text
    return r.json()["id"]


def _finished(bench: ProtocolBench, run_id: str, ceiling_s: float) -> dict:
    assert bench.client is not None
    client = bench.client
    return wait_for(lambda: (run := client.get(f"/api/tests/{run_id}").json())["status"]
                    in ("completed", "failed", "aborted", "interrupted") and run, timeout_s=ceiling_s)


def _load_until_trigger(bench: ProtocolBench) -> dict:
    """Start the loading test and return the simulator's status once |torque| >= 600 N·m (the drive powering)."""
    _post(bench, LOAD)
    # the first pass through 600 N·m comes after 600/200 = 3 s simulated; the ceiling allows a slow start
    return wait_for(lambda: (s := bench.control(cmd="status"))["drive"]["state"] == "OPERATION ENABLED"
                    and abs(s["applied_torque_nm"]) >= TRIGGER_TORQUE_NM and s, timeout_s=120, interval_s=0.01)


def _drive_stopped_by_itself(bench: ProtocolBench, since: float) -> tuple[float, dict]:
    """(seconds from ``since`` to the drive watchdog's reaction, as the simulator recorded it; the simulator's
    status once the drive is disabled or in fault at |torque| < 20 N·m)."""
    reaction = wait_for(lambda: [r for r in bench.control(cmd="status")["watchdog_reactions"]
                                 if r["at_monotonic_s"] >= since], timeout_s=30)[0]
    status = wait_for(lambda: (s := bench.control(cmd="status"))["drive"]["state"] not in POWERED
                      and abs(s["applied_torque_nm"]) < SAFE_TORQUE_NM and s, timeout_s=30)
    print(f"{bench.loader}: watchdog {reaction['reaction']} {reaction['at_monotonic_s'] - since:.3f} s after the "
          f"trigger ({reaction['silent_s']:.3f} s of silence); drive {status['drive']['state']}, "
          f"{status['applied_torque_nm']:.1f} N·m")
    return reaction["at_monotonic_s"] - since, status


def _next_test_completes(bench: ProtocolBench) -> None:
    run = completes_on_a_loaded_bench(lambda: _finished(bench, _post(bench, NEXT), ceiling_s=300))
    assert run["status"] == "completed", run["error"]
    assert 250 < run["results"]["rigidity_nm_per_arcmin"] < 350


@pytest.mark.slow
@pytest.mark.timeout(900)
@pytest.mark.parametrize("loader", ["canopen", "modbus"])
def test_service_killed_under_torque_the_drive_stops_by_itself(protocol_bench, loader):
    bench = protocol_bench(loader)
    loaded = _load_until_trigger(bench)
    killed_at = bench.kill_service()
    stop_s, stopped = _drive_stopped_by_itself(bench, killed_at)
    assert abs(loaded["applied_torque_nm"]) >= TRIGGER_TORQUE_NM
    assert stopped["drive"]["state"] == "FAULT" and stopped["drive"]["error_code"] == 0x8130
    assert stop_s <= STOP_BOUND_S, stop_s
    # a restarted service reports what its safe start found (the drive in FAULT 0x8130, no torque), in its log, its
    # events' source (/api/bench) and the run cut off by the kill; then the next test completes
    bench.start_service()
    assert bench.client is not None
    status = bench.client.get("/api/bench").json()
    found = status["safe_start"]
    assert found["found_state"] == "FAULT" and found["found_error_code"] == 0x8130 and found["safe"], found
    assert status["not_ready"] is None
    wait_for(lambda: any("safe start:" in line and "found FAULT 0x8130" in line for line in bench.output))
    _next_test_completes(bench)


@pytest.mark.slow
@pytest.mark.timeout(900)
@pytest.mark.parametrize("loader", ["canopen", "modbus"])
def test_link_mute_under_torque_the_drive_stops_by_itself(protocol_bench, loader):
    """The loader's link goes silent (Modbus server swallowing requests; the socketcand hub dropping every frame):
    the drive stops by itself, the service's test ends aborted, and after the link is back the next test completes."""
    bench = protocol_bench(loader)
    link = "modbus" if loader == "modbus" else "socketcand"
    _load_until_trigger(bench)
    muted_at = time.monotonic()
    bench.control(cmd="inject", instrument=link, fault="mute")
    stop_s, stopped = _drive_stopped_by_itself(bench, muted_at)
    assert stopped["drive"]["state"] == "FAULT" and stopped["drive"]["error_code"] == 0x8130
    assert stop_s <= STOP_BOUND_S, stop_s
    assert bench.client is not None
    client = bench.client
    # while the link is mute the service never shows its last loader reading as live: the link is down or stale
    muted = wait_for(lambda: (v := client.get("/api/bench").json()["instruments"]["loader"])["link"] != "up" and v,
                     timeout_s=60)
    assert muted["status"]["live"] is False and muted["age_s"] > 0.1, muted
    runs = bench.client.get("/api/tests").json()
    run = _finished(bench, runs[0]["id"], ceiling_s=120)
    assert run["status"] == "aborted" and "loader" in run["error"], run["error"]
    bench.control(cmd="inject", instrument=link, fault=None)
    # the service sees the drive's real state again (no stale reading shown as live)
    wait_for(lambda: (v := bench.client.get("/api/bench").json()["instruments"]["loader"]).get("status")
             and v["status"]["live"] and v["status"]["state"] == "FAULT", timeout_s=60)
    _next_test_completes(bench)


@pytest.mark.slow
@pytest.mark.timeout(900)
def test_without_a_drive_watchdog_the_restarted_service_makes_the_drive_safe(protocol_bench):
    """The issue's report: a Modbus drive without its watchdog keeps full torque when the service dies. The restarted
    service's safe start finds it enabled under torque, ramps it to zero and disables it before any test."""
    bench = protocol_bench("modbus", watchdog=False)
    _load_until_trigger(bench)
    killed_at = bench.kill_service()
    still = bench.control(cmd="status")
    assert still["drive"]["state"] == "OPERATION ENABLED" and still["watchdog_reactions"] == []
    bench.start_service()
    assert bench.client is not None
    found = bench.client.get("/api/bench").json()["safe_start"]
    assert found["found_state"] == "OPERATION ENABLED" and abs(found["found_torque_nm"]) >= TRIGGER_TORQUE_NM, found
    assert found["safe"] and found["final_state"] == "SWITCH ON DISABLED", found
    after = bench.control(cmd="status")
    assert after["drive"]["state"] == "SWITCH ON DISABLED" and abs(after["applied_torque_nm"]) < SAFE_TORQUE_NM
    print(f"no watchdog: the restarted service found {found['found_state']} at {found['found_torque_nm']:.0f} N·m, "
          f"safe {time.monotonic() - killed_at:.1f} s after the kill (restart included)")
    _next_test_completes(bench)

"""Helpers of the service tests: a uvicorn server in a thread on an ephemeral loopback port.

``ScriptedRunner`` is a test double of the bench runner (the Runner protocol of tcms_daq.service.runner): it
produces a synthetic hysteresis loop (linear spring + constant-width friction band) in real time, so the HTTP,
WebSocket, store and abort paths can be tested without the acquisition layer. End-to-end tests use the real
runner over the simulated bench.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import threading
import time
import tomllib
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import tomli_w
import uvicorn
from tcms_daq.sim.instruments.child import stop_process

from tcms_daq.analysis.gaps import TOO_FEW_LOOPS_LEFT
from tcms_daq.config.loader import resolve_config_path
from tcms_daq.service.app import ServiceSettings, create_app
from tcms_daq.service.runner import RUN_CHANNELS, AcceptedTest, RequestRejected, RunOutcome

TOKEN = "test-token-123"


class ScriptedRunner:
    """Synthetic bench: idle noise at ``rate_hz`` and triangle torque profiles during tests (real time)."""

    channels = RUN_CHANNELS

    def __init__(self, rate_hz: float = 2000.0, batch_s: float = 0.01, speed: float = 10.0,
                 bench_name: str = "scripted bench", bench_id: str | None = None, results: dict | None = None):
        self.results = results if results is not None else {"rigidity_nm_per_arcmin": 294.0 * 1.0101, "passed": True}
        self.bench_name = bench_name
        self.bench_id = bench_id
        self.rate_hz = rate_hz
        self.batch_s = batch_s
        self.speed = speed  # simulated seconds per real second during a test
        self._live = None
        self._stop = threading.Event()
        self._test_active = threading.Event()
        self._t = 0.0
        self._lock = threading.Lock()
        self._thread: threading.Thread | None = None
        self.compensation = "[compensator]\nterms = []\n"

    def open(self, live_sink) -> None:
        self._live = live_sink
        self._thread = threading.Thread(target=self._idle, daemon=True)
        self._thread.start()

    def close(self) -> None:
        self._stop.set()
        if self._thread:
            self._thread.join(2)

    def _emit(self, torque: np.ndarray, record=None) -> None:
        with self._lock:
            n = len(torque)
            t = self._t + np.arange(n) / self.rate_hz
            self._t = float(t[-1]) + 1 / self.rate_hz
        direction = np.sign(np.gradient(torque)) if n > 1 else np.zeros(n)
        enc = torque / 294.0 * 60.0 + 10.0 * direction
        cols = {"time_s": t, "torque_nm": torque, "angle_arcsec": enc * 0.99, "encoder_arcsec": enc}
        if record is not None:
            record(cols)
        self._live(cols)

    def _idle(self) -> None:
        n = int(self.rate_hz * self.batch_s)
        rng = np.random.default_rng(0)
        while not self._stop.wait(self.batch_s):
            if not self._test_active.is_set():
                self._emit(rng.normal(0, 0.3, n))

    def status(self) -> dict:
        return {"name": "scripted bench", "config": None, "max_torque_nm": 1000.0, "clock": "monotonic",
                "connected": True, "compensation": None, "instruments": {}, "last_interlock": None,
                "samples_published": 0,
                "reducers": [{"name": "RV-110E", "kind": "RV", "rated_torque_nm": 1078.0,
                              "max_test_torque_nm": 1000.0}],
                "test_bounds": {"max_torque_nm": 1000.0, "min_rate_nm_per_s": 0.05, "max_rate_nm_per_s": 1000.0,
                                "min_step_nm": 0.1, "max_test_duration_s": 3600.0, "max_segments": 20000}}

    def config_snapshot(self) -> dict:
        return {"bench": {"name": self.bench_name, **({"id": self.bench_id} if self.bench_id else {})}}

    def compensator_toml(self) -> str:
        return self.compensation

    def set_compensator_toml(self, text: str) -> None:
        if "[compensator]" not in text:
            raise RequestRejected("compensation TOML needs a [compensator] table")
        self.compensation = text

    def compensation_checks(self):
        from tcms_daq.config.models import CompensationChecks

        return CompensationChecks()

    def plan(self, request) -> AcceptedTest:
        if request.reducer != "RV-110E":
            raise RequestRejected(f"unknown reducer {request.reducer!r} (known: RV-110E)")
        if request.max_torque_nm > 1000.0:
            raise RequestRejected(f"max_torque_nm {request.max_torque_nm:g} exceeds the bench limit 1000 N·m")
        rate = request.rate_nm_per_s or 200.0
        legs = [-1.0, 1.0] * request.cycles + [-1.0]
        return AcceptedTest(request, {"kind": request.profile, "legs": len(legs)}, (rate, legs))

    def execute(self, plan, *, run_id, record, on_phase, abort) -> RunOutcome:
        rate, legs = plan.payload
        T = plan.request.max_torque_nm
        self._test_active.set()
        try:
            on_phase("loading")
            torque_now = 0.0
            step = rate * self.batch_s
            for leg in legs:
                target = leg * T
                while abs(target - torque_now) > 1e-9:
                    if abort.is_set():
                        return RunOutcome("aborted")
                    n = int(self.rate_hz * self.batch_s)
                    nxt = torque_now + np.clip(target - torque_now, -step, step)
                    self._emit(np.linspace(torque_now, nxt, n), record)
                    torque_now = nxt
                    time.sleep(self.batch_s / self.speed)
            on_phase("evaluating")
            return RunOutcome("completed", results=self.results)
        finally:
            self._test_active.clear()


class LiveServer:
    def __init__(self, app, sock: socket.socket):
        self.app = app
        self.port = sock.getsockname()[1]
        self.base = f"http://127.0.0.1:{self.port}"
        self.ws_base = f"ws://127.0.0.1:{self.port}"
        self.server = uvicorn.Server(uvicorn.Config(app, log_level="warning", ws_per_message_deflate=False))
        self.thread = threading.Thread(target=self.server.run, kwargs={"sockets": [sock]}, daemon=True)

    def __enter__(self) -> LiveServer:
        self.thread.start()
        deadline = time.monotonic() + 120  # a ceiling: the wait ends when uvicorn has started (or its thread died)
        while not self.server.started:
            if time.monotonic() > deadline or not self.thread.is_alive():
                raise RuntimeError("service did not start")
            time.sleep(0.02)
        return self

    def __exit__(self, *exc) -> None:
        self.server.should_exit = True
        self.thread.join(20)

    def client(self, token: str | None = TOKEN) -> httpx.Client:
        headers = {"Authorization": f"Bearer {token}"} if token else {}
        return httpx.Client(base_url=self.base, headers=headers, timeout=20)


@contextmanager
def serve(settings: ServiceSettings, runner=None) -> Iterator[LiveServer]:
    sock = socket.socket()
    sock.bind(("127.0.0.1", 0))
    app = create_app(settings, runner=runner)
    with LiveServer(app, sock) as server:
        yield server


def wait_for(predicate: Callable[[], object], timeout_s: float = 20.0, interval_s: float = 0.05):
    """Poll ``predicate`` until it returns something truthy (connection errors count as not yet)."""
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            value = predicate()
        except httpx.TransportError:
            value = None
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError("condition not met in time")
        time.sleep(interval_s)


GAP_REFUSAL = TOO_FEW_LOOPS_LEFT  # in the run's error when gaps left too few loops


def completes_on_a_loaded_bench(run_test: Callable[[], dict], attempts: int = 3) -> dict:
    """The first test of up to ``attempts`` that does not fail for gaps in the data: on a loaded machine a stall of
    the real-time protocol bench leaves a gap, and a run rightly refuses to evaluate across it (issue 22); that
    says nothing of whether the bench works again. Any other outcome is returned at once."""
    for _ in range(attempts - 1):
        run = run_test()
        if not (run["status"] == "failed" and GAP_REFUSAL in (run.get("error") or "")):
            return run
        print(f"refused for gaps (a stall of the loaded bench), run again: {run['error']}")
    return run_test()


def start_serve_process(args: list[str], *, cwd=None, timeout_s: float = 300.0) -> tuple[subprocess.Popen, str]:
    """``tcms serve ARGS`` as a child process (token ``TOKEN``); (process, base URL) once it printed its URL (its
    readiness; a child that exits ends the wait at once, ``timeout_s`` is a ceiling for one that hangs)."""
    env = {**os.environ, "TCMS_API_TOKEN": TOKEN, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen([sys.executable, "-m", "tcms_daq.cli", "serve", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, env=env, cwd=cwd)
    deadline = time.monotonic() + timeout_s
    seen = []
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        seen.append(line)
        if "service on http://" in line:
            return proc, "http://" + line.split("http://", 1)[1].split("/", 1)[0]
        if not line and proc.poll() is not None:
            break
    stop_process(proc)
    raise AssertionError(f"tcms serve did not start: {''.join(seen)!r}")


def kill_during_a_run(proc: subprocess.Popen, base: str, request: dict, *, timeout_s: float = 60.0) -> str:
    """Start a test on the service at ``base``, SIGKILL the service (no shutdown hook runs) once the test is
    running with more than 500 samples stored; the test's id."""
    try:
        c = httpx.Client(base_url=base, headers={"Authorization": f"Bearer {TOKEN}"}, timeout=20)
        wait_for(lambda: c.get("/api/health").status_code == 200)
        run_id = c.post("/api/tests", json=request).json()["id"]
        wait_for(lambda: (t := c.get(f"/api/tests/{run_id}").json())["status"] == "running"
                 and t["sample_count"] > 500, timeout_s=timeout_s)
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(10)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
    return run_id


def _u_entry(value: float, u: float, k: float, unit: str, dominant: str) -> dict:
    """One entry of the shared result contract's ``uncertainty`` table (issue 11's shape)."""
    return {"value": value, "u": u, "U": k * u, "k": k, "dof": 41.0, "unit": unit, "dominant": dominant,
            "budget": [{"source": dominant, "type": "B", "u_input": 0.001, "sensitivity": value,
                        "contribution": u}]}


def results_with_uncertainty(decision: str = "pass") -> dict:
    """Results as an evaluation with issue 11's uncertainty and decision keys writes them (injected by tests of
    their consumers): rigidity 293.94 ± 2.3 (k = 2.05), lost motion 41.27 ± 0.82 (k = 2.0), backlash 18.6 ±
    1.2 (k = 2.0); a guarded decision."""
    return {
        "rigidity_nm_per_arcmin": 293.94, "lost_motion_arcsec": 41.27, "backlash_arcsec": 18.6,
        "loading_rate_nm_per_s": 400.0, "test_torque_nm": 200.0, "n_loops": 1,
        "uncertainty": {
            "rigidity_nm_per_arcmin": _u_entry(293.94, 1.1219512, 2.05, "N·m/arcmin", "torque scale"),
            "lost_motion_arcsec": _u_entry(41.27, 0.41, 2.0, "arcsec", "encoder interpolation"),
            "backlash_arcsec": _u_entry(18.6, 0.6, 2.0, "arcsec", "loop-to-loop scatter"),
        },
        "uncertainty_basis": "declared chain: bench config",
        "verdict": {"passed": decision == "pass", "decision": decision, "rule": "guarded", "checks": {
            "rigidity_min_nm_per_arcmin": {"label": "rigidity ≥ 235.2 N·m/arcmin", "value": 293.94, "limit": 235.2,
                                           "passed": True, "decision": "pass", "guard_band": 2.3},
            "lost_motion_max_arcsec": {"label": "lost motion ≤ 60 arcsec", "value": 41.27, "limit": 60.0,
                                       "passed": decision == "pass", "decision": decision, "guard_band": 0.82}}},
        "warnings": [],
    }


def loopback_config_with_loader(path: Path, loader: str, urls: dict[str, str], **loader_options: Any) -> Path:
    """Write to ``path`` the packaged loopback bench with its loader table replaced by the CANopen or the Modbus TCP
    drive at ``urls`` (``tcms sim serve``'s), plus ``loader_options``; returns ``path``."""
    packaged = resolve_config_path("bench-loopback.toml")
    cfg = tomllib.loads(packaged.read_text(encoding="utf-8"))
    for key in ("compensation", "reducers"):
        cfg["bench"][key] = str(packaged.parent / cfg["bench"][key])
    cfg["sim"]["geometry"] = str(packaged.parent / cfg["sim"]["geometry"])
    cfg["instruments"]["loader"] = ({**cfg["instruments"]["loader"], "url": urls["loader_canopen"]}
                                    if loader == "canopen" else
                                    {"driver": "cia402-modbus", "url": urls["loader_modbus"]})
    cfg["instruments"]["loader"].update(loader_options)
    path.write_text(tomli_w.dumps(cfg), encoding="utf-8")
    return path


STATION_METHODS = ("transmission-error", "starting-torque", "no-load-torque", "efficiency")


def station_runs(data_dir: Path, methods: tuple[str, ...] = STATION_METHODS, reducer: str = "RV-110E",
                 sim_speed: float = 20.0, **request: Any) -> dict[str, str]:
    """Run each turning method once on the simulated station (config/bench-station.toml, in-process, through the
    service as a client would) into the store in ``data_dir``; {method: run id} once every run has completed."""
    from tcms_daq.config.loader import resolve_config_path

    settings = ServiceSettings(data_dir=data_dir, api_token=TOKEN, config_path=resolve_config_path("bench-station.toml"),
                               sim_speed=sim_speed)
    ids = {}
    with serve(settings) as server:
        c = server.client()
        for method in methods:
            answer = c.post("/api/tests", json={"reducer": reducer, "method": method, **request})
            assert answer.status_code == 202, answer.text
            run_id = answer.json()["id"]
            run = wait_for(lambda: (r := c.get(f"/api/tests/{run_id}").json())["status"]  # noqa: B023
                           in ("completed", "failed", "aborted") and r, timeout_s=120)
            assert run["status"] == "completed", (method, run["error"])
            ids[method] = run_id
    return ids

"""The service's cost against real time (issue 16 item 2): ``tcms serve`` on the simulated bench at several
``--sim-speed`` values, in its own process.

Per speed: the service's CPU (user + system, from /proc) over ``idle_s`` of wall time with no test running, in
cores; then one test (RV-110E, ±800 N·m, 3 cycles at 100 N·m/s) from the POST to its completion: the simulated
duration of the test (recorded samples / sample rate) over the wall time, the *achieved speed*, and the CPU
over the test. min/median/max of ``RUNS`` runs per speed.
"""

from __future__ import annotations

import sys
import tempfile
import time
import tomllib
from pathlib import Path

import httpx
from tcms_daq.sim.instruments.child import stop_process

from benchmarks._runs import RUNS, spread
from benchmarks.live_pipeline import TOKEN, _cpu_seconds, _start_service

REPO = Path(__file__).resolve().parents[1]
SPEEDS = (1.0, 25.0, 100.0)
IDLE_CORES_LIMIT_AT_100 = 0.1
ACHIEVED_SPEED_LIMIT_AT_100 = 60.0
TEST = {"reducer": "RV-110E", "max_torque_nm": 800, "cycles": 3, "rate_nm_per_s": 100}


def _sample_rate_hz() -> float:
    return float(tomllib.loads((REPO / "config" / "bench-sim.toml").read_text(encoding="utf-8"))["sim"]
                 ["sample_rate_hz"])


def _one(speed: float, tmp: Path, idle_s: float, run_test: bool) -> dict[str, float]:
    proc, hostport = _start_service(REPO / "config" / "bench-sim.toml", tmp / f"data-{speed:g}-{time.time_ns()}",
                                    sim_speed=speed)
    try:
        client = httpx.Client(base_url=f"http://{hostport}", timeout=30,
                              headers={"Authorization": f"Bearer {TOKEN}"})
        time.sleep(2.0)  # past the start-up
        c0, w0 = _cpu_seconds(proc.pid), time.monotonic()
        time.sleep(idle_s)
        out = {"idle_cores": (_cpu_seconds(proc.pid) - c0) / (time.monotonic() - w0)}
        if run_test:
            c0, w0 = _cpu_seconds(proc.pid), time.monotonic()
            run = client.post("/api/tests", json=TEST).json()
            while True:
                rec = client.get(f"/api/tests/{run['id']}").json()
                if rec["status"] not in ("queued", "running"):
                    break
                time.sleep(0.05)
            wall = time.monotonic() - w0
            if rec["status"] != "completed":
                raise RuntimeError(f"test ended {rec['status']}: {rec.get('error')}")
            simulated_s = rec["sample_count"] / _sample_rate_hz()
            out.update({"test_wall_s": wall, "test_simulated_s": simulated_s, "achieved_speed": simulated_s / wall,
                        "test_cores": (_cpu_seconds(proc.pid) - c0) / wall})
        client.close()
        return out
    finally:
        stop_process(proc)


def run(quick: bool = False) -> dict:
    idle_s = 3.0 if quick else 10.0
    metrics: dict[str, float | str] = {}
    targets: dict[str, dict] = {}
    with tempfile.TemporaryDirectory(prefix="tcms-bench-pacing-") as tmp:
        for speed in SPEEDS:
            runs = [_one(speed, Path(tmp), idle_s, run_test=speed > 1) for _ in range(1 if quick else RUNS)]
            k = f"speed_{speed:g}"
            for key in runs[0]:
                metrics.update(spread(f"{k}_{key}", [r[key] for r in runs]))
    if "speed_100_idle_cores_max" in metrics:
        targets["speed_100_idle_cores_max"] = {"limit": IDLE_CORES_LIMIT_AT_100,
                                               "met": metrics["speed_100_idle_cores_max"] <= IDLE_CORES_LIMIT_AT_100}
        targets["speed_100_achieved_speed_min"] = {
            "limit": ACHIEVED_SPEED_LIMIT_AT_100,
            "met": metrics["speed_100_achieved_speed_min"] >= ACHIEVED_SPEED_LIMIT_AT_100}
    return {
        "name": "service_pacing",
        "metrics": metrics,
        "targets": targets,
        "notes": (f"tcms serve (bench-sim.toml, {_sample_rate_hz():g} Hz) in its own process per run; idle CPU over "
                  f"{idle_s:g} s with no test; one test {TEST}: achieved speed = recorded samples / sample rate / "
                  "wall time from POST to completion; min/median/max over the runs."),
    }


if __name__ == "__main__":  # pragma: no cover
    import json

    print(json.dumps(run(quick="--full" not in sys.argv), indent=2))

"""Memory of one long run (issue 10 item 6): peak growth per sample and memory retained after a run.

``tcms serve`` runs as a separate process on the simulated bench sampling at 5 kHz (simulated clock at
``SIM_SPEED``× real time, so a 100 s test takes seconds). A short warm-up test and its exports load every code path, then the
resident set (``VmRSS`` from /proc) is the baseline and the peak counter ``VmHWM`` is reset (``clear_refs``); a
test of about 500 000 samples runs to completion; the service is then idle for a moment.

* ``peak_growth_b_per_sample``: (VmHWM during the run − baseline) / samples stored;
* ``retained_mb``: VmRSS after the run − baseline;
* ``csv_export_peak_mb``, ``json_export_peak_mb``: peak growth while that run is downloaded (streamed), beside
  the size of the file.

If the kernel refuses ``clear_refs`` the peak is taken from VmRSS sampled every 10 ms (a lower bound).
``RUNS`` runs, each with a fresh service; min/median/max over the runs, a target judged on the worst run.
"""

from __future__ import annotations

import os
import tempfile
import threading
import time
from pathlib import Path

import httpx
from tcms_daq.sim.instruments.child import stop_process

from benchmarks._runs import RUNS, spread
from benchmarks.live_pipeline import TOKEN, _bench_config, _start_service

SAMPLE_RATE_HZ = 5_000.0
TARGET_SAMPLES = 500_000
SIM_SPEED = 10.0
PEAK_LIMIT_B_PER_SAMPLE = 100.0
RETAINED_LIMIT_MB = 60.0
# RV-110E, a conditioning loop and one evaluated loop from -T: about 10·T/rate with the start, tips and stop
REQUEST = {"reducer": "RV-110E", "max_torque_nm": 1000.0, "cycles": 1}


def _status_kb(pid: int) -> dict[str, int]:
    out = {}
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        key, _, value = line.partition(":")
        if key in ("VmRSS", "VmHWM"):
            out[key] = int(value.split()[0])
    return out


def _reset_peak(pid: int) -> bool:
    try:
        Path(f"/proc/{pid}/clear_refs").write_text("5")
    except OSError:
        return False
    return True


def _run_test(client: httpx.Client, body: dict, timeout_s: float) -> dict:
    run_id = client.post("/api/tests", json=body).json()["id"]
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        status = client.get(f"/api/tests/{run_id}").json()
        if status["status"] not in ("queued", "running"):
            return status
        time.sleep(0.2)
    client.post(f"/api/tests/{run_id}/abort")
    raise RuntimeError(f"test {run_id} did not finish within {timeout_s} s")


def _one_run(quick: bool) -> dict:
    target = TARGET_SAMPLES // 5 if quick else TARGET_SAMPLES
    rate = 10.0 * REQUEST["max_torque_nm"] / (target / SAMPLE_RATE_HZ)
    with tempfile.TemporaryDirectory(prefix="tcms-mem-") as tmp:
        workdir = Path(tmp)
        config = _bench_config(workdir, SAMPLE_RATE_HZ)
        proc, hostport = _start_service(config, workdir / "data", sim_speed=SIM_SPEED)
        try:
            headers = {"Authorization": f"Bearer {TOKEN}"}
            with httpx.Client(base_url=f"http://{hostport}", headers=headers, timeout=30) as client:
                warm = _run_test(client, {**REQUEST, "rate_nm_per_s": 2000.0}, 120)
                if warm["status"] != "completed":
                    raise RuntimeError(f"warm-up test {warm['status']}: {warm.get('error')}")
                for fmt in ("csv", "json"):  # first use of the exporters (imports, Arrow's memory pool)
                    client.get(f"/api/tests/{warm['id']}/samples", params={"format": fmt})
                time.sleep(1.0)
                baseline_kb = _status_kb(proc.pid)["VmRSS"]
                exact_peak = _reset_peak(proc.pid)
                sampled_peak_kb = [baseline_kb]
                stop = threading.Event()

                def sample() -> None:
                    while not stop.wait(0.01):
                        sampled_peak_kb.append(_status_kb(proc.pid)["VmRSS"])

                sampler = threading.Thread(target=sample, daemon=True)
                sampler.start()
                status = _run_test(client, {**REQUEST, "rate_nm_per_s": round(rate, 3)}, 600)
                stop.set()
                sampler.join()
                peak_kb = _status_kb(proc.pid)["VmHWM"] if exact_peak else max(sampled_peak_kb)
                if status["status"] != "completed":
                    raise RuntimeError(f"test {status['status']}: {status.get('error')}")
                time.sleep(2.0)
                after_kb = _status_kb(proc.pid)["VmRSS"]
                samples = int(status["sample_count"])
                export_peak_kb = {}
                for fmt in ("csv", "json"):
                    before_kb = _status_kb(proc.pid)["VmRSS"]
                    _reset_peak(proc.pid)
                    size = 0
                    with client.stream("GET", f"/api/tests/{status['id']}/samples", params={"format": fmt}) as r:
                        for block in r.iter_bytes():
                            size += len(block)
                    export_peak_kb[fmt] = (_status_kb(proc.pid)["VmHWM"] - before_kb, size)
        finally:
            stop_process(proc)
    return {
        "samples": samples,
        "baseline_rss_mb": baseline_kb / 1024.0,
        "peak_growth_b_per_sample": (peak_kb - baseline_kb) * 1024.0 / samples,
        "retained_mb": (after_kb - baseline_kb) / 1024.0,
        "peak_measured_by": "VmHWM" if exact_peak else "VmRSS every 10 ms",
        **{f"{fmt}_export_peak_mb": kb / 1024.0 for fmt, (kb, _) in export_peak_kb.items()},
        **{f"{fmt}_export_size_mb": size / 2**20 for fmt, (_, size) in export_peak_kb.items()},
    }


def run(quick: bool = False) -> dict:
    runs = [_one_run(quick) for _ in range(1 if quick else RUNS)]
    metrics: dict[str, float | str] = {
        "runs": len(runs),
        "peak_measured_by": ", ".join(sorted({r["peak_measured_by"] for r in runs})),
    }
    for key in runs[0]:
        if key != "peak_measured_by":
            metrics.update(spread(key, [r[key] for r in runs]))
    peak_b = float(metrics["peak_growth_b_per_sample_max"])
    retained_mb = float(metrics["retained_mb_max"])
    return {
        "name": "run_memory",
        "metrics": metrics,
        "targets": {
            "peak_growth_b_per_sample_max": {"limit": PEAK_LIMIT_B_PER_SAMPLE, "met": peak_b <= PEAK_LIMIT_B_PER_SAMPLE},
            "retained_mb_max": {"limit": RETAINED_LIMIT_MB, "met": retained_mb <= RETAINED_LIMIT_MB},
        },
        "notes": (f"{len(runs)} runs, a fresh tcms serve each (5 kHz simulated bench at sim speed {SIM_SPEED:g}); "
                  "min/median/max over the runs; targets judged on the worst run."),
    }


if __name__ == "__main__":
    import json

    print(json.dumps(run(quick=bool(os.environ.get("QUICK"))), indent=2))

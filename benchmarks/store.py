"""Run store insert rate (issue 7 item 5, issue 16 item 4): sustained sample inserts into the SQLite (WAL) run
store against writing the same bytes to a plain file, measured in the same run, at two durability levels.

The workload is what the recorder does during a test: 4 float64 channels (time, torque, compensated angle, raw
encoder angle) arriving in 20 ms acquisition batches (1000 samples at 50 kHz) and committed every 0.2 s, i.e.
10 batches per transaction. The store path is ``RunStore.append_samples`` (one channel-major float64 blob per
batch, one transaction per commit). Two durability levels, each against its plain-file equal:

* crash-safe: ``synchronous=NORMAL`` against appending the blobs to an open file flushed once per commit (both
  survive a crash of the process, neither a power cut);
* power-safe: ``synchronous=FULL`` against the file flushed and ``fsync``-ed once per commit.

min/median/max over three runs; the rounds alternate store and file.
"""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks._runs import RUNS, spread
from tcms_daq.store import RunStore

CHANNELS = ("time_s", "torque_nm", "angle_arcsec", "encoder_arcsec")
BATCH_SAMPLES = 1000  # 20 ms at 50 kHz
BATCHES_PER_COMMIT = 10  # the recorder commits every 0.2 s
FASTEST_SOURCE_HZ = 50_000.0  # Heidenhain Ethernet interface electronics (issue 7 item 2)
TARGET_HEADROOM = 10.0  # the store must sustain at least 10× the fastest source


def _batches(n_batches: int, seed: int = 0) -> list[dict[str, np.ndarray]]:
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n_batches):
        t = (i * BATCH_SAMPLES + np.arange(BATCH_SAMPLES)) / FASTEST_SOURCE_HZ
        torque = 1000.0 * np.sin(0.3 * t) + rng.normal(0.0, 0.3, BATCH_SAMPLES)
        angle = torque / 294.0 * 60.0 + rng.normal(0.0, 0.2, BATCH_SAMPLES)
        out.append({"time_s": t, "torque_nm": torque, "angle_arcsec": angle, "encoder_arcsec": angle * 1.001})
    return out


def _store_rate(directory: Path, batches: list[dict[str, np.ndarray]], synchronous: str) -> float:
    with RunStore(directory / "bench.sqlite3", synchronous=synchronous) as store:
        store.create_run("bench", {"benchmark": True}, CHANNELS)
        started = time.perf_counter()
        for i in range(0, len(batches), BATCHES_PER_COMMIT):
            store.append_samples("bench", batches[i : i + BATCHES_PER_COMMIT])
        elapsed = time.perf_counter() - started
        n = store.get_run("bench").sample_count
    return n / elapsed


def _file_rate(directory: Path, batches: list[dict[str, np.ndarray]], fsync: bool) -> float:
    path = directory / "bench.f64"
    n = 0
    started = time.perf_counter()
    with path.open("wb") as f:
        for i in range(0, len(batches), BATCHES_PER_COMMIT):
            for cols in batches[i : i + BATCHES_PER_COMMIT]:
                block = np.stack([np.asarray(cols[c], dtype="<f8") for c in CHANNELS])
                f.write(block.tobytes())
                n += block.shape[1]
            f.flush()
            if fsync:
                os.fsync(f.fileno())
    elapsed = time.perf_counter() - started
    return n / elapsed


def run(quick: bool = False) -> dict:
    n_batches = 500 if quick else 5000  # 0.5 M / 5 M samples (16 / 160 MB of float64)
    repeats = 1 if quick else RUNS
    batches = _batches(n_batches)
    n = n_batches * BATCH_SAMPLES
    limit = TARGET_HEADROOM * FASTEST_SOURCE_HZ
    metrics: dict[str, float] = {"samples": n}
    targets = {}
    for level, synchronous, fsync in (("crash_safe", "NORMAL", False), ("power_safe", "FULL", True)):
        store_rates, file_rates = [], []
        for _ in range(repeats):
            with tempfile.TemporaryDirectory(prefix="tcms-bench-store-") as tmp:
                store_rates.append(_store_rate(Path(tmp), batches, synchronous))
            with tempfile.TemporaryDirectory(prefix="tcms-bench-store-") as tmp:
                file_rates.append(_file_rate(Path(tmp), batches, fsync))
        ratios = [s / f for s, f in zip(store_rates, file_rates, strict=True)]
        for name, values in (("store_samples_per_s", store_rates), ("file_samples_per_s", file_rates),
                             ("store_to_file_ratio", ratios)):
            metrics.update(spread(f"{level}_{name}", values))
        metrics[f"{level}_store_mb_per_s_median"] = metrics[f"{level}_store_samples_per_s_median"] * 8 * len(CHANNELS) / 1e6
        metrics[f"{level}_headroom_over_50khz_source_min"] = min(store_rates) / FASTEST_SOURCE_HZ
        targets[f"{level}_store_samples_per_s_min"] = {"limit": limit, "met": min(store_rates) >= limit}
    return {
        "name": "store",
        "metrics": metrics,
        "targets": targets,
        "notes": (
            f"{n} samples × {len(CHANNELS)} float64 channels in {BATCH_SAMPLES}-sample batches, "
            f"{BATCHES_PER_COMMIT} batches per commit; min/median/max of {repeats} runs. crash_safe: SQLite WAL "
            "synchronous=NORMAL against a plain file flushed per commit; power_safe: synchronous=FULL against a plain "
            f"file flushed and fsync-ed per commit. Target: at least {TARGET_HEADROOM:g}× the fastest source (50 kHz)."
        ),
    }


if __name__ == "__main__":  # pragma: no cover
    import json

    print(json.dumps(run(quick=True), indent=2))

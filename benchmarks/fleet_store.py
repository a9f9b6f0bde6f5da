"""Fleet store (issue 14): 8 simulated benches at 5 kHz each into one PostgreSQL, without loss; insert rate and CPU.

Each bench is what a service runs during a test: its own :class:`PostgresRunStore` (its own connection pool and
bench id) and the service's :class:`Recorder` committing every 0.2 s (one binary COPY per commit, a row per
acquisition batch); a producer thread per bench hands it 4 float64 channels in 20 ms batches (100 samples at
5 kHz), paced in real time. The server is a throwaway PostgreSQL with fsync on (``ThrowawayPostgres(durable=True)``).

* paced: every bench at 5 kHz for ``duration``; lossless when every produced sample is in the database, in order
  and bit for bit (checked by reading every run back); the commit latency of the recorders (max); CPU of this
  process and of the PostgreSQL server (postmaster and its backends), as cores busy over the run.
* capacity: the same 8 writers committing 10-batch transactions as fast as they can: the insert rate the database
  sustains, as a multiple of the fleet's 40 kS/s.

min/median/max over the repeats.
"""

from __future__ import annotations

import os
import statistics
import threading
import time
from pathlib import Path

import numpy as np

from tcms_daq.store import Recorder
from tcms_daq.store.pgserver import ThrowawayPostgres, pg_bin_dir
from tcms_daq.store.postgres_store import PostgresRunStore

CHANNELS = ("time_s", "torque_nm", "angle_arcsec", "encoder_arcsec")
BENCHES = 8
RATE_HZ = 5000.0
BATCH_S = 0.02
BATCH = int(RATE_HZ * BATCH_S)  # 100 samples per acquisition batch
FLUSH_S = 0.2  # the service's recorder interval
TICKS = os.sysconf("SC_CLK_TCK")


def _batch(index: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
    t = (index * BATCH + np.arange(BATCH)) / RATE_HZ
    torque = 1000.0 * np.sin(0.3 * t) + rng.normal(0.0, 0.3, BATCH)
    angle = torque / 294.0 * 60.0 + rng.normal(0.0, 0.2, BATCH)
    return {"time_s": t, "torque_nm": torque, "angle_arcsec": angle, "encoder_arcsec": angle * 1.001}


def _cpu_s(pids: list[int]) -> float:
    total = 0
    for pid in pids:
        try:
            fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        total += int(fields[11]) + int(fields[12])  # utime + stime
    return total / TICKS


class _TimedRecorder(Recorder):
    """The service's recorder, keeping the duration of each commit."""

    def __init__(self, *args, **kwargs):
        self.commit_s: list[float] = []
        super().__init__(*args, **kwargs)

    def flush(self) -> int:
        started = time.perf_counter()
        n = super().flush()
        if n:
            self.commit_s.append(time.perf_counter() - started)
        return n


def _paced(url: str, server: ThrowawayPostgres, duration_s: float, seed: int) -> dict[str, float]:
    stores = [PostgresRunStore(url, bench_id=f"bench-{i}", bench_name=f"bench {i}") for i in range(BENCHES)]
    run_ids = [f"paced-{seed}-{i}" for i in range(BENCHES)]
    recorders = []
    for store, run_id in zip(stores, run_ids, strict=True):
        store.create_run(run_id, {"reducer": "RV-110E", "benchmark": True}, CHANNELS)
        store.set_status(run_id, "running")
        recorders.append(_TimedRecorder(store, run_id, flush_interval_s=FLUSH_S))
    n_batches = int(duration_s / BATCH_S)
    produced = [0] * BENCHES
    late = [0.0] * BENCHES

    def produce(i: int) -> None:
        rng = np.random.default_rng(seed * 100 + i)
        start = time.perf_counter()
        for k in range(n_batches):
            due = start + (k + 1) * BATCH_S
            wait = due - time.perf_counter()
            if wait > 0:
                time.sleep(wait)
            else:
                late[i] = max(late[i], -wait)
            recorders[i].write(_batch(k, rng))
            produced[i] += BATCH

    pids = server.server_pids()
    cpu0, pg0, wall0 = time.process_time(), _cpu_s(pids), time.perf_counter()
    threads = [threading.Thread(target=produce, args=(i,)) for i in range(BENCHES)]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    written = sum(r.close() for r in recorders)
    wall = time.perf_counter() - wall0
    cpu, pg = time.process_time() - cpu0, _cpu_s(server.server_pids() or pids) - pg0
    lost = 0
    for i, (store, run_id) in enumerate(zip(stores, run_ids, strict=True)):
        cols = store.read_columns(run_id)
        rng = np.random.default_rng(seed * 100 + i)  # the producer's batches again, in order
        made = [_batch(k, rng) for k in range(n_batches)]
        same = all(np.array_equal(cols[c], np.concatenate([b[c] for b in made])) for c in CHANNELS
                   if len(cols[c]) == n_batches * BATCH)
        lost += abs(n_batches * BATCH - len(cols["time_s"])) or (0 if same else 1)
        store.set_status(run_id, "completed")
    for store in stores:
        store.close()
    commits = [c for r in recorders for c in r.commit_s]
    return {"samples": float(sum(produced)), "written": float(written), "lost": float(lost), "wall_s": wall,
            "insert_samples_per_s": written / wall, "client_cpu_cores": cpu / wall, "server_cpu_cores": pg / wall,
            "commit_s_median": statistics.median(commits), "commit_s_max": max(commits),
            "producer_late_s_max": max(late)}


def _capacity(url: str, duration_s: float, seed: int) -> float:
    stores = [PostgresRunStore(url, bench_id=f"cap-{i}", bench_name=f"cap {i}") for i in range(BENCHES)]
    rng = np.random.default_rng(seed)
    batches = [_batch(k, rng) for k in range(10)]
    counts = [0] * BENCHES
    stop = time.perf_counter() + duration_s

    def write(i: int) -> None:
        run_id = f"cap-{seed}-{i}"
        stores[i].create_run(run_id, {"benchmark": True}, CHANNELS)
        while time.perf_counter() < stop:
            counts[i] += stores[i].append_samples(run_id, batches)

    started = time.perf_counter()
    threads = [threading.Thread(target=write, args=(i,)) for i in range(BENCHES)]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    elapsed = time.perf_counter() - started
    for store in stores:
        store.close()
    return sum(counts) / elapsed


def _spread(values: list[float]) -> tuple[float, float, float]:
    v = sorted(values)
    return v[0], statistics.median(v), v[-1]


def run(quick: bool = False) -> dict:
    bin_dir = pg_bin_dir()
    if bin_dir is None:
        raise RuntimeError("no PostgreSQL server binaries: run `bash scripts/setup`")
    duration = 5.0 if quick else 60.0
    capacity_s = 2.0 if quick else 10.0
    repeats = 1 if quick else 3
    fleet_rate = BENCHES * RATE_HZ
    metrics: dict[str, float] = {"benches": BENCHES, "rate_per_bench_hz": RATE_HZ, "duration_s": duration,
                                 "load_average_1min_before": os.getloadavg()[0]}
    with ThrowawayPostgres(bin_dir, durable=True) as server:
        import psycopg

        with psycopg.connect(server.url(), autocommit=True) as conn:
            conn.execute("CREATE DATABASE fleet")
        url = server.url("fleet")
        paced = [_paced(url, server, duration, seed) for seed in range(repeats)]
        capacity = [_capacity(url, capacity_s, seed) for seed in range(repeats)]
    for key in ("insert_samples_per_s", "client_cpu_cores", "server_cpu_cores", "commit_s_median", "commit_s_max",
                "producer_late_s_max"):
        lo, mid, hi = _spread([p[key] for p in paced])
        metrics.update({f"paced_{key}_min": lo, f"paced_{key}_median": mid, f"paced_{key}_max": hi})
    metrics["paced_samples_lost_total"] = sum(p["lost"] for p in paced)
    metrics["paced_samples_written_total"] = sum(p["written"] for p in paced)
    lo, mid, hi = _spread(capacity)
    metrics.update({"capacity_samples_per_s_min": lo, "capacity_samples_per_s_median": mid,
                    "capacity_samples_per_s_max": hi, "capacity_over_fleet_rate_min": lo / fleet_rate})
    metrics["load_average_1min_after"] = os.getloadavg()[0]
    return {
        "name": "fleet_store",
        "metrics": metrics,
        "targets": {"paced_samples_lost_total": {"limit": 0, "met": metrics["paced_samples_lost_total"] == 0},
                    "capacity_over_fleet_rate_min": {"limit": 1.0, "met": lo / fleet_rate >= 1.0}},
        "notes": (f"{BENCHES} benches × {RATE_HZ:g} Hz × {len(CHANNELS)} float64 channels, {BATCH}-sample batches, "
                  f"recorder commits every {FLUSH_S:g} s (one binary COPY each), each bench its own store and pool; "
                  f"throwaway PostgreSQL with fsync on; paced {duration:g} s; capacity: 8 unpaced writers, 10 "
                  f"batches per commit, {capacity_s:g} s; min/median/max of {repeats}. CPU in cores busy."),
    }


if __name__ == "__main__":  # pragma: no cover
    import json

    print(json.dumps(run(quick=True), indent=2))

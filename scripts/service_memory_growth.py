"""Is the service's memory growth over many tests a leak? (issue 22, bounded resources)

Starts ``tcms serve`` (the simulated bench, a fast clock) with tracemalloc tracing in the service process, runs
``--first`` tests, snapshots, runs ``--tests`` more, snapshots again, and prints: the resident set after each
stage, what Python's allocations grew by between the two snapshots (total and the top lines), and the size of one
run's samples as the service holds them (samples × columns × 8 bytes), so a growth can be compared with "one run
leaked per test". The snapshots are taken in the service on SIGUSR1 and written next to its data directory.

Usage: ``.venv/bin/python scripts/service_memory_growth.py [--first 10] [--tests 40] [--top 12]``
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
import tracemalloc
from pathlib import Path

import httpx

TOKEN = "memory-growth-token"
REQUEST = {"reducer": "RV-110E", "max_torque_nm": 300, "cycles": 1, "rate_nm_per_s": 600}

# what runs inside the service process: tracing from the start, a snapshot to SNAPSHOT_PATH on SIGUSR1
SERVICE = """
import os, signal, sys, tracemalloc
tracemalloc.start(8)
def dump(signum, frame):
    import gc
    gc.collect()
    path = os.environ["SNAPSHOT_PATH"]
    tracemalloc.take_snapshot().dump(path + ".part")
    os.replace(path + ".part", path)
signal.signal(signal.SIGUSR1, dump)
from tcms_daq.cli import main
sys.exit(main(["serve", *sys.argv[1:]]))
"""


def _rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    raise RuntimeError("no VmRSS")


def _wait(predicate, ceiling_s: float, what: str, interval_s: float = 0.05):
    deadline = time.monotonic() + ceiling_s
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(interval_s)
    raise TimeoutError(f"{what} not within {ceiling_s:g} s")


def _run_tests(c: httpx.Client, n: int) -> dict:
    last: dict = {}
    for _ in range(n):
        run_id = c.post("/api/tests", json=REQUEST).json()["id"]
        last = _wait(lambda rid=run_id: (r := c.get(f"/api/tests/{rid}").json())["status"]
                     not in ("queued", "running") and r, 300, f"test {run_id}")
        if last["status"] != "completed":
            raise RuntimeError(f"test {run_id} ended {last['status']}: {last.get('error')}")
    _wait(lambda: c.get("/api/bench").json().get("active_test") is None, 60, "the service idle")
    return last


def _snapshot(proc: subprocess.Popen, path: Path) -> tracemalloc.Snapshot:
    path.unlink(missing_ok=True)
    os.kill(proc.pid, signal.SIGUSR1)
    _wait(path.exists, 120, "the snapshot")
    return tracemalloc.Snapshot.load(str(path))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--first", type=int, default=10, help="tests before the first snapshot")
    parser.add_argument("--tests", type=int, default=40, help="tests between the two snapshots")
    parser.add_argument("--top", type=int, default=12, help="lines of the growth to print")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        snap_path = Path(tmp) / "snapshot.bin"
        env = {**os.environ, "TCMS_API_TOKEN": TOKEN, "PYTHONUNBUFFERED": "1", "SNAPSHOT_PATH": str(snap_path)}
        proc = subprocess.Popen([sys.executable, "-c", SERVICE, "--port", "0", "--data-dir", str(Path(tmp) / "data"),
                                 "--sim-speed", "1000"], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                                env=env)
        assert proc.stdout is not None
        base = ""
        for line in proc.stdout:
            if "service on http://" in line:
                base = "http://" + line.split("http://", 1)[1].split("/", 1)[0]
                break
        if not base:
            raise RuntimeError("tcms serve did not start")
        threading.Thread(target=lambda: [None for _ in proc.stdout], daemon=True).start()  # keep the pipe drained
        try:
            with httpx.Client(base_url=base, headers={"Authorization": f"Bearer {TOKEN}"}, timeout=60) as c:
                _wait(lambda: c.get("/api/health").status_code == 200, 60, "the service healthy")
                last = _run_tests(c, args.first)
                rss_first = _rss_mb(proc.pid)
                first = _snapshot(proc, snap_path)
                _run_tests(c, args.tests)
                rss_last = _rss_mb(proc.pid)
                second = _snapshot(proc, snap_path)
        finally:
            proc.terminate()
            proc.wait(30)
    samples = int(last.get("sample_count") or 0)
    columns = 4  # time, torque, angle, torque interval (the service keeps the canonical three and the gap columns)
    run_mb = samples * columns * 8 / 1e6
    stats = second.compare_to(first, "lineno")
    grown = sum(s.size_diff for s in stats) / 1e6
    print(f"RSS after test {args.first}: {rss_first:.1f} MB; after test {args.first + args.tests}: {rss_last:.1f} MB "
          f"(+{rss_last - rss_first:.1f} MB, {(rss_last - rss_first) / args.tests * 1e3:.0f} kB per test)")
    print(f"Python allocations traced: {grown:+.2f} MB over {args.tests} tests "
          f"({grown / args.tests * 1e3:+.1f} kB per test)")
    print(f"one run's samples: {samples} samples × {columns} columns × 8 B = {run_mb:.2f} MB "
          f"(a leak of them per test: {run_mb * args.tests:.1f} MB over {args.tests} tests)")
    print("largest growths (file:line, size difference, count difference):")
    for stat in stats[:args.top]:
        frame = stat.traceback[0]
        print(f"  {frame.filename}:{frame.lineno}  {stat.size_diff / 1e3:+.1f} kB  {stat.count_diff:+d}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""1 M samples from CSV to verdict (issue 24 item 6: within 10 s on this machine, the README states the figure).

Data: the hidden-effect trial design (RV-110E, ±800 N·m loops at 200 and 600 N·m/s) sampled at 13.75 kHz
(1 000 312 rows per file), the torque noise at the trials' density, a 20 ms time skew hidden; the two files are
written by the project's CSV writer. Measured: ``tcms discrepancy measured.csv simulated.csv --json`` as a separate
process, end to end (start-up, reading both files, the workflow, the JSON), wall clock and the process's CPU; three
runs. The verdict must be ``explained`` with the skew named within 1 %.
"""

from __future__ import annotations

import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks._runs import RUNS, spread
from tcms_daq.discrepancy import effects as fx

RATE_HZ = 13_750.0
SKEW_S = 0.02
MAX_WALL_S = 10.0


def write_pair(folder: Path, rate_hz: float = RATE_HZ) -> int:
    """The measured and simulated CSV files of the hidden skew at ``rate_hz``; the number of rows."""
    from tcms_daq.sim.trials import TrialDesign, make_pair

    from tcms_daq.samples import csv_bytes

    base = TrialDesign()
    design = TrialDesign(sample_rate_hz=rate_hz,
                         torque_noise_nm=base.torque_noise_nm * (base.sample_rate_hz / rate_hz) ** 0.5)
    measured, simulated, _ = make_pair({fx.TIME_SKEW: {"skew_s": SKEW_S}}, 1, design)
    for name, samples in (("measured", measured), ("simulated", simulated)):
        cols = {"time_s": samples.time_s, "torque_nm": samples.torque_nm, "angle_arcsec": samples.angle_arcsec}
        (folder / f"{name}.csv").write_bytes(csv_bytes(cols))
    return len(measured)


def _cli(folder: Path) -> tuple[float, float, dict]:
    """(wall s, CPU s of the child, the JSON result) of one ``tcms discrepancy … --json``."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    out = subprocess.run([sys.executable, "-m", "tcms_daq.cli", "discrepancy", str(folder / "measured.csv"),
                          str(folder / "simulated.csv"), "--json"], capture_output=True, text=True, check=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu, json.loads(out.stdout)


def run(quick: bool = False) -> dict:
    runs = 1 if quick else RUNS
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        rows = write_pair(folder, RATE_HZ / 10 if quick else RATE_HZ)
        size_mb = sum((folder / f"{n}.csv").stat().st_size for n in ("measured", "simulated")) / 1e6
        walls, cpus, result = [], [], {}
        for _ in range(runs):
            wall, cpu, result = _cli(folder)
            walls.append(wall)
            cpus.append(cpu)
    named = {e["name"]: e["parameters"] for e in result.get("effects", [])}
    skew = named.get(fx.TIME_SKEW, {}).get("skew_s", float("nan"))
    right = list(named) == [fx.TIME_SKEW] and abs(skew / SKEW_S - 1) <= 0.01
    metrics = {"rows_per_file": rows, "csv_mb_both_files": size_mb, **spread("cli_wall_s", walls),
               **spread("cli_cpu_s", cpus), "verdict": result.get("verdict"), "named": ",".join(named),
               "skew_s": skew, "named_correctly": right}
    targets = {"cli_wall_s_max": {"limit": MAX_WALL_S, "met": max(walls) <= MAX_WALL_S},
               "verdict": {"limit": "explained", "met": result.get("verdict") == "explained"},
               "named_correctly": {"limit": True, "met": right}}
    return {"name": "discrepancy_csv", "metrics": metrics, "targets": targets,
            "notes": f"tcms discrepancy measured.csv simulated.csv --json, {runs} runs; hidden {fx.TIME_SKEW} "
                     f"{SKEW_S} s at {RATE_HZ / 10 if quick else RATE_HZ:g} Hz"}


if __name__ == "__main__":
    print(json.dumps(run(), indent=1))

"""The README's table of the simulated reducers: ``tcms run --reducer R --json`` (seed 0, compensated) for each,
printed as the README's rows (value ± U rounded to two significant digits of U / the simulator's truth).

Run: ``.venv/bin/python scripts/reducer_table.py``."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from tcms_daq.analysis.rounding import round_to_uncertainty

REDUCERS = ("RV-110E", "RV-100C", "RV-60N", "HFUC-32-100")
QUANTITIES = ("rigidity_nm_per_arcmin", "lost_motion_arcsec", "backlash_arcsec")
TCMS = Path(sys.executable).with_name("tcms")


def row(reducer: str) -> str:
    out = subprocess.run([str(TCMS), "run", "--reducer", reducer, "--json"], capture_output=True, text=True,
                         check=True).stdout
    run = json.loads(out)
    result = run.get("result", run)
    truth = run.get("truth", result.get("truth", {}))
    cells = []
    for name in QUANTITIES:
        entry = result["uncertainty"][name]
        value, expanded = round_to_uncertainty(float(entry["value"]), float(entry["U"]))
        cells.append(f"{value} ± {expanded} / {float(truth[name]):.2f}")
    return f"| {reducer} | " + " | ".join(cells) + " |"


if __name__ == "__main__":
    for reducer in REDUCERS:
        print(row(reducer), flush=True)

"""The README's tables of the turning tests on the simulated station: ``tcms run --config bench-station.toml --reducer
R --method M --json`` (seed 0, compensated, the methods' default programmes) for RV-110E and HFUC-32-100, printed as
the README's rows: each result as value ± U (rounded to two significant digits of U) / the simulated unit's exact
truth, and whether it lies within U.

Run: ``.venv/bin/python scripts/method_table.py`` (about a minute: eight runs)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from tcms_daq.analysis.rounding import round_to_uncertainty

REDUCERS = ("RV-110E", "HFUC-32-100")
METHODS = ("transmission-error", "starting-torque", "no-load-torque", "efficiency")
TCMS = Path(sys.executable).with_name("tcms")


def _label(name: str, results: dict) -> str:
    components = {f"te_order_{ln['order']:.4g}_amplitude_arcsec": ln.get("component") or "no component"
                  for ln in results.get("te_orders") or []}
    return f"{name} ({components[name]})" if name in components else name


def rows(reducer: str, method: str) -> list[str]:
    out = subprocess.run([str(TCMS), "run", "--config", "bench-station.toml", "--reducer", reducer, "--method",
                          method, "--json"], capture_output=True, text=True, check=True).stdout
    run = json.loads(out)
    truth, table, within = run["truth"], run["uncertainty"], run["within_u"]
    lines = []
    for name, expected in truth.items():
        entry = table.get(name)
        if entry is None:
            lines.append(f"| {reducer} | `{name}` | not found | {expected:.4g} | no |")
            continue
        value, expanded = round_to_uncertainty(float(entry["value"]), float(entry["U"]))
        lines.append(f"| {reducer} | `{_label(name, run)}` | {value} ± {expanded} | {expected:.4g} | "
                     f"{'yes' if within[name] else 'no'} |")
    return lines


if __name__ == "__main__":
    for method in METHODS:
        print(f"\n{method}\n\n| unit | result | evaluated ± U | truth | within U |\n|---|---|---|---|---|")
        for reducer in REDUCERS:
            for line in rows(reducer, method):
                print(line, flush=True)

"""The discrepancy workflow adds what it finds to the bench model, and the gap closes on new data.

A simulated RV-110E bench with a hidden thermal drift (0.03″/s) makes two stored runs (different seeds, so
run 2 is data the effect was not chosen on). ``tcms discrepancy --run run-1 --apply`` names the drift and adds
it as bench model version 1; ``tcms discrepancy --run run-2`` compares run 2 against version 1. The same
archive and store code answer ``POST /api/discrepancy`` and ``POST /api/discrepancy/{id}/apply`` in the
service (tests/service/test_service_discrepancy.py walks that path on the real-time service).

    python scripts/discrepancy_apply_demo.py            # prints the figures the README quotes
"""

from __future__ import annotations

import contextlib
import io
import json
import sys
import tempfile
from pathlib import Path

from tcms_daq.sim.trials import bench_run

from tcms_daq.cli import main
from tcms_daq.store import STORE_FILENAME, RunStore

HIDDEN = {"thermal_drift": {"rate_arcsec_per_s": 0.03}}


def tcms_json(*argv: str) -> dict:
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        code = main(list(argv))
    if code != 0:
        raise SystemExit(f"tcms {' '.join(argv)} exited {code}")
    return json.loads(out.getvalue())


def demo(data_dir: Path) -> list[dict]:
    with RunStore(data_dir / STORE_FILENAME) as store:
        for run_id, seed in (("run-1", 51), ("run-2", 52)):
            samples = bench_run(HIDDEN, seed)[0]
            store.create_run(run_id, {"reducer": "RV-110E"}, ("time_s", "torque_nm", "angle_arcsec"),
                             status="completed")
            store.append_samples(run_id, [{"time_s": samples.time_s, "torque_nm": samples.torque_nm,
                                           "angle_arcsec": samples.angle_arcsec}])
    first = tcms_json("discrepancy", "--run", "run-1", "--data-dir", str(data_dir), "--json", "--apply")
    second = tcms_json("discrepancy", "--run", "run-2", "--data-dir", str(data_dir), "--json")
    return [first, second]


def describe(doc: dict) -> str:
    named = ", ".join(f"{e['name']} {e['parameters'][next(iter(e['parameters']))]:.4g} ± "
                      f"{e['standard_uncertainty'].get(next(iter(e['parameters'])), float('nan')):.2g}"
                      for e in doc["effects"]) or "nothing"
    applied = f"; applied as bench model version {doc['applied_version']}" if doc.get("applied_version") else ""
    return (f"{doc['run_id']} against bench model v{doc['model_version']}: {doc['verdict']}; named {named}; "
            f"held-out RMS {doc['cv_rms_before_arcsec']:.3f}″ → {doc['cv_rms_after_arcsec']:.3f}″ "
            f"(noise floor {doc['noise_floor_arcsec']:.3f}″){applied}")


if __name__ == "__main__":
    with tempfile.TemporaryDirectory() as tmp:
        for doc in demo(Path(tmp)):
            print(describe(doc))
    sys.exit(0)

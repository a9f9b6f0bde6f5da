"""``tcms discrepancy MEASURED.csv SIMULATED.csv``: name the effects missing from the simulation.

Both files are canonical sample CSVs (DESIGN §9). The simulation may have the measured rows, its own time grid
(put onto the measured stamps in the common span), a clock offset (estimated and reported) or another torque
trace such as the commanded one (compared branch by branch at equal torque); what cannot be compared is refused
with the reason. An optional ``run_id`` column groups runs. Without ``time_s`` the time-dependent effects are not candidates. ``--out DIR`` writes
``report.html``, ``model.toml`` and ``resimulated.csv``; ``--json`` prints the result object.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

from tcms_daq.errors import DataFormatError
from tcms_daq.samples import Samples, read_csv_columns, samples_from_columns
from tcms_daq.settings import read_settings


def read_pair_file(path: str | Path) -> tuple[Samples, bool]:
    """A sample CSV for the workflow (torque_nm and angle_arcsec required; time_s optional) and has_time."""
    cols = read_csv_columns(path, required=("torque_nm", "angle_arcsec"))
    return samples_from_columns(cols), "time_s" in cols


def run(args: argparse.Namespace) -> int:
    # imported here: the workflow, scipy and matplotlib would slow every `tcms` command's start by a second
    from tcms_daq.analysis.evaluation import jsonable
    from tcms_daq.discrepancy.report import format_text
    from tcms_daq.discrepancy.workflow import run_discrepancy
    from tcms_daq.store.discrepancy import write_outputs

    if args.table4:
        return run_table4_report(args)
    if args.apply and args.run is None:
        raise DataFormatError("--apply adds the effects a stored run's analysis names: give --run ID")
    if args.run is not None:
        return run_stored(args)
    else:
        if args.measured is None or args.simulated is None:
            raise DataFormatError("give MEASURED.csv and SIMULATED.csv (or --run ID)")
        measured, t_m = read_pair_file(args.measured)
        simulated, t_s = read_pair_file(args.simulated)
        if t_m != t_s:
            raise DataFormatError("time_s is in one file but not in the other: the files are not aligned")
        has_time = t_m
        title = f"Discrepancy report: {Path(args.measured).name} vs {Path(args.simulated).name}"
    if not (args.signal_period_arcsec > 0 and math.isfinite(args.signal_period_arcsec)):
        raise DataFormatError(f"--signal-period-arcsec must be > 0 (got {args.signal_period_arcsec})")
    result = run_discrepancy(measured, simulated, signal_period_arcsec=args.signal_period_arcsec, has_time=has_time)
    if args.out:
        write_outputs(result, measured, simulated, args.out, title)
    if args.json:
        print(json.dumps(jsonable(result.to_dict()), indent=1))
    else:
        print(format_text(result))
        if args.out:
            print(f"wrote {Path(args.out) / 'report.html'}, model.toml, resimulated.csv")
    return 0


def run_stored(args: argparse.Namespace) -> int:
    """``tcms discrepancy --run ID [--apply]``: the stored run against the bench model in use, kept in the
    data directory's archive of analyses (as ``POST /api/discrepancy``); ``--apply`` adds what it names to the
    bench model as its next version (as ``POST /api/discrepancy/{id}/apply``)."""
    from tcms_daq.discrepancy.report import parameters_text
    from tcms_daq.sim.physics import catalogue_model
    from tcms_daq.store import STORE_FILENAME, RunStore
    from tcms_daq.store.discrepancy import ANALYSES_DIRNAME, AnalysisArchive

    data_dir = Path(args.data_dir or read_settings().data_dir)
    path = data_dir / STORE_FILENAME
    if not path.exists():
        raise DataFormatError(f"no run store at {path} (give --data-dir)")
    archive = AnalysisArchive(data_dir / ANALYSES_DIRNAME)
    store = RunStore(path, recover=False)  # a service may be running a test in it right now
    try:
        if store.get_run(args.run) is None:
            raise DataFormatError(f"unknown run {args.run!r} in {path}")
        doc = archive.analyse(store, args.run, catalogue_model, signal_period_arcsec=args.signal_period_arcsec)
        added = archive.apply(store, doc["id"], accept_provisional=args.accept_provisional) if args.apply else None
    finally:
        store.close()
    if args.out:
        import shutil

        shutil.copytree(archive.root / doc["id"], args.out, dirs_exist_ok=True)
    if args.json:
        print(json.dumps({**doc, "applied_version": added.version if added else None}, indent=1))
        return 0
    print(f"analysis {doc['id']} of run {args.run} against bench model version {doc['model_version']}")
    print(f"verdict: {doc['verdict']} — {doc['verdict_words']}")
    for e in doc["effects"]:
        params = parameters_text(e["parameters"], e.get("expanded_uncertainty") or {}, e.get("coverage_factor"))
        print(f"named{' (provisional)' if e.get('provisional') else ''}: {e['name']} ({params})")
    print(f"held-out RMS {doc['cv_rms_before_arcsec']:.3f}″ → {doc['cv_rms_after_arcsec']:.3f}″")
    if added is not None:
        print(f"bench model version {added.version}: {added.note}")
    return 0


def table4_fixed_models() -> tuple[list[str], ...]:
    """Fixed effect sets compared with the workflow's choice on Table 4 (docs/discrepancy.md)."""
    from tcms_daq.discrepancy import effects as fx

    return ([], [fx.SCALE_ERROR], [fx.TORSION_OFFSET], [fx.SCALE_ERROR, fx.TORSION_OFFSET],
            [fx.INTERPOLATION_ERROR], [fx.SCALE_ERROR, fx.INTERPOLATION_ERROR], [fx.PERIODIC_ERROR],
            [fx.SCALE_ERROR, fx.PERIODIC_ERROR], [fx.BENDING_DEFORMATION])


def run_table4_report(args: argparse.Namespace) -> int:
    """``tcms discrepancy --table4``: the paper's Table 4 through the workflow, with fixed models beside it."""
    from tcms_daq.analysis.evaluation import jsonable
    from tcms_daq.discrepancy.report import format_text
    from tcms_daq.discrepancy.table4 import fixed_model_cv, run_table4, table4_pair
    from tcms_daq.store.discrepancy import write_outputs

    result = run_table4()
    raw = run_table4(simulated_column="encoder_arcsec")
    compare = {"+".join(n) or "offset only": fixed_model_cv(n) for n in table4_fixed_models()}
    if args.out:
        measured, simulated = table4_pair()
        write_outputs(result, measured, simulated, args.out, "Discrepancy report: the paper's Table 4")
    if args.json:
        print(json.dumps(jsonable({**result.to_dict(), "fixed_model_cv_rms_arcsec": compare,
                                   "raw_encoder_as_simulation": raw.to_dict()}), indent=1))
        return 0
    print(format_text(result))
    print("blocked-CV RMS of fixed models (single level, for comparison):")
    for k, v in compare.items():
        print(f"  {k:40s} {v:.3f}″")
    print(f"selected in outer folds: {result.groups['nested_selections']}")
    print("\nthe raw (uncompensated) encoder as the simulation:")
    print(format_text(raw))
    print(f"selected in outer folds: {raw.groups['nested_selections']}")
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "discrepancy",
        help="name the effects missing from a simulation (measured vs simulated CSV)",
        description=__doc__.split("\n\n")[0].replace("``", ""),
    )
    p.add_argument("measured", nargs="?", metavar="MEASURED.csv", help="measured samples (canonical CSV)")
    p.add_argument("simulated", nargs="?", metavar="SIMULATED.csv", help="simulated samples: the same rows, or its own time grid, clock offset or torque trace")
    p.add_argument("--signal-period-arcsec", type=float, default=72.0,
                   help="encoder signal period (72 for the RON 786)")
    p.add_argument("--out", metavar="DIR", help="write report.html, model.toml and resimulated.csv here")
    p.add_argument("--json", action="store_true", help="print the result as one JSON object")
    p.add_argument("--run", metavar="ID", help="a stored run against the bench model re-simulated on its torque")
    p.add_argument("--data-dir", metavar="DIR", help="data directory of the run store (with --run)")
    p.add_argument("--apply", action="store_true",
                   help="with --run: add the named effects to the bench model (its next version)")
    p.add_argument("--accept-provisional", action="store_true",
                   help="with --apply: add them even when the verdict leaves their names provisional")
    p.add_argument("--table4", action="store_true",
                   help="the paper's Table 4: autocollimator as measured, the paper's compensated encoder as "
                   "simulated (docs/discrepancy.md)")
    p.set_defaults(func=run)

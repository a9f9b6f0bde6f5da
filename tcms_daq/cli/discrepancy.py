"""``tcms discrepancy MEASURED.csv SIMULATED.csv``: name the effects missing from the simulation.

Both files are canonical sample CSVs (DESIGN §9) with the same rows in the same order; an optional ``run_id``
column groups runs. Without ``time_s`` the time-dependent effects are not candidates. ``--out DIR`` writes
``report.html``, ``model.toml`` and ``resimulated.csv``; ``--json`` prints the result object.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

from tcms_daq.analysis.evaluation import jsonable
from tcms_daq.errors import DataFormatError
from tcms_daq.samples import Samples, read_csv_columns, samples_from_columns


def read_pair_file(path: str | Path) -> tuple[Samples, bool]:
    """A sample CSV for the workflow (torque_nm and angle_arcsec required; time_s optional) and has_time."""
    cols = read_csv_columns(path, required=("torque_nm", "angle_arcsec"))
    return samples_from_columns(cols), "time_s" in cols




def write_outputs(result, measured: Samples, simulated: Samples, out_dir: str | Path, title: str) -> list[Path]:
    from tcms_daq.discrepancy.model_file import model_from_result, resimulated_samples
    from tcms_daq.discrepancy.report import render_html
    from tcms_daq.samples import write_csv

    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise DataFormatError(f"{out}: cannot create the output directory ({exc})") from None
    paths = [out / "report.html", out / "model.toml", out / "resimulated.csv"]
    paths[0].write_text(render_html(result, title=title), encoding="utf-8")
    model_from_result(result).save(paths[1])
    write_csv(paths[2], resimulated_samples(result, simulated, measured))
    return paths


def format_result(result) -> str:
    lines = []
    if result.effects:
        for e in result.effects:
            params = ", ".join(f"{k}={v:.4g}" for k, v in e.parameters.items())
            lines.append(f"named: {e.name} ({params}); held-out RMS {e.cv_rms_before_arcsec:.3f}″ → "
                         f"{e.cv_rms_after_arcsec:.3f}″")
    else:
        lines.append("named: nothing (no catalogue effect improves the held-out error reliably)")
    for a in result.aliases:
        kept = ""
        if a.in_model:
            params = ", ".join(f"{k}={v:.4g}" for k, v in a.parameters.items())
            kept = f" (in the model as {a.representative}: {params})"
        lines.append(f"aliases: {', '.join(a.names)} cannot be told apart here{kept} — {a.separating_experiment}")
    for r in result.rejected:
        lines.append(f"rejected: {r['name']}: {r['reason']}")
    lines.append(f"RMS {result.rms_before_arcsec:.3f}″ → {result.rms_after_arcsec:.3f}″, max "
                 f"{result.max_before_arcsec:.3f}″ → {result.max_after_arcsec:.3f}″, held-out RMS "
                 f"{result.cv_rms_before_arcsec:.3f}″ → {result.cv_rms_after_arcsec:.3f}″ (nested CV over "
                 f"{result.groups['count']} {result.groups['kind']})")
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    from tcms_daq.discrepancy.workflow import run_discrepancy

    if args.run is not None:
        from tcms_daq.discrepancy.stored import stored_pair

        measured, simulated = stored_pair(args.run, args.data_dir)
        has_time = True
        title = f"Discrepancy report: stored run {args.run}"
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
        print(format_result(result))
        if args.out:
            print(f"wrote {Path(args.out) / 'report.html'}, model.toml, resimulated.csv")
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "discrepancy",
        help="name the effects missing from a simulation (measured vs simulated CSV)",
        description=__doc__.split("\n\n")[0].replace("``", ""),
    )
    p.add_argument("measured", nargs="?", metavar="MEASURED.csv", help="measured samples (canonical CSV)")
    p.add_argument("simulated", nargs="?", metavar="SIMULATED.csv", help="simulated samples, same rows")
    p.add_argument("--signal-period-arcsec", type=float, default=72.0,
                   help="encoder signal period (72 for the RON 786)")
    p.add_argument("--out", metavar="DIR", help="write report.html, model.toml and resimulated.csv here")
    p.add_argument("--json", action="store_true", help="print the result as one JSON object")
    p.add_argument("--run", metavar="ID", help="a stored run against the bench model re-simulated on its torque")
    p.add_argument("--data-dir", metavar="DIR", help="data directory of the run store (with --run)")
    p.set_defaults(func=run)

"""``tcms analyze FILE.csv``: evaluate a recorded hysteresis test (canonical CSV, DESIGN §9)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from tcms_daq.analysis import evaluate, format_evaluation
from tcms_daq.errors import EvaluationError
from tcms_daq.samples import read_csv


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "analyze",
        help="evaluate a recorded test CSV (rigidity, lost motion, backlash)",
        description="Evaluate the hysteresis loops of a canonical sample CSV (columns time_s, torque_nm, "
        "angle_arcsec): torsional rigidity (secant of the midline over an interval of the test torque, both "
        "sides averaged), lost motion at ±P %% of rated torque, backlash (loop width at 0 Nm), per direction "
        "and mean ± std over loops.",
    )
    p.add_argument("file", type=Path, metavar="FILE.csv", help="canonical sample CSV")
    p.add_argument("--rated-torque", type=float, required=True, metavar="NM",
                   help="rated torque of the reducer in N·m (sets the lost-motion torque level)")
    p.add_argument("--lost-motion-pct", type=float, default=3.0, metavar="P",
                   help="lost-motion torque level in %% of rated torque (default 3; Harmonic Drive 4, Yaskawa 5)")
    p.add_argument("--test-torque", type=float, default=None, metavar="NM",
                   help="test torque amplitude in N·m (default: the torque reached at the turning points, "
                   "taken as the rated torque when within 2 %%)")
    p.add_argument("--interval", type=float, nargs=2, default=(0.5, 1.0), metavar=("LO", "HI"),
                   help="rigidity interval as fractions of the test torque on each side (default 0.5 1.0; "
                   "values above 1 are read as percent, e.g. 50 100)")
    p.add_argument("--skip-loops", type=int, default=0, metavar="N",
                   help="report but do not average the first N full loops (e.g. 1 conditioning loop; default 0)")
    p.add_argument("--hd-breakpoints", type=float, nargs=2, default=None, metavar=("T1", "T2"),
                   help="Harmonic Drive breakpoints in N·m: also fit K1, K2, K3 (N·m/rad)")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of the table")
    p.set_defaults(func=run)


def _interval(values: tuple[float, float]) -> tuple[float, float]:
    lo, hi = values
    if hi > 1.0:
        lo, hi = lo / 100.0, hi / 100.0
    if not 0.0 <= lo < hi <= 1.0:
        raise EvaluationError(f"--interval must satisfy 0 <= LO < HI <= 1 (or percent up to 100), got {values[0]:g} {values[1]:g}")
    return lo, hi


def run(args: argparse.Namespace) -> int:
    samples = read_csv(args.file)
    ev = evaluate(
        samples.time_s,
        samples.torque_nm,
        samples.angle_arcsec,
        rated_torque_nm=args.rated_torque,
        test_torque_nm=args.test_torque,
        lost_motion_pct=args.lost_motion_pct,
        rigidity_interval=_interval(tuple(args.interval)),
        hd_breakpoints_nm=tuple(args.hd_breakpoints) if args.hd_breakpoints else None,
        skip_loops=args.skip_loops,
    )
    if args.json:
        print(json.dumps({"file": str(args.file), **ev.to_dict()}, allow_nan=False))
    else:
        print(f"{args.file}: {ev.n_samples} samples over {ev.duration_s:.1f} s")
        print(format_evaluation(ev))
    return 0

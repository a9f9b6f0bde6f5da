"""``tcms analyze FILE.csv``: evaluate a recorded hysteresis test (canonical CSV, DESIGN §9)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from tcms_daq.analysis import format_evaluation
from tcms_daq.analysis.evaluation import EvaluationSettings
from tcms_daq.cli.options import add_decision_rule_option
from tcms_daq.config import ReducerSpec
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
    p.add_argument("--rated-torque", type=float, default=None, metavar="NM",
                   help="rated torque of the reducer in N·m (sets the lost-motion torque level); required "
                   "unless --reducer is given")
    p.add_argument("--reducer", default=None, metavar="NAME",
                   help="catalogue reducer (e.g. RV-110E): rated torque, lost-motion level, Harmonic Drive "
                   "breakpoints and pass/fail limits from the catalogue; explicit options override them")
    p.add_argument("--catalogue", type=Path, default=None, metavar="FILE",
                   help="reducer catalogue TOML (default: config/reducers.toml)")
    p.add_argument("--lost-motion-pct", type=float, default=None, metavar="P",
                   help="lost-motion torque level in %% of rated torque (default 3, or the catalogue's; "
                   "Harmonic Drive 4, Yaskawa 5)")
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
    p.add_argument("--uncertainty", type=Path, default=None, metavar="FILE.toml",
                   help="declared standard uncertainties (k = 1) of the measuring chain: [torque] u_rel, u_zero_nm; "
                   "[angle] u_rel, u_arcsec, u_interpolation_arcsec, signal_period_arcsec; [compensation] u_rel, "
                   "u_torsion_arcsec_per_knm; [temperature] u_k and its coefficients (docs/uncertainty.md). "
                   "Without it: Type A only (the loop-to-loop scatter)")
    add_decision_rule_option(p)
    p.add_argument("--json", action="store_true", help="print one JSON object instead of the table")
    p.set_defaults(func=run)


def _interval(values: tuple[float, float]) -> tuple[float, float]:
    lo, hi = values
    if hi > 1.0:
        lo, hi = lo / 100.0, hi / 100.0
    if not 0.0 <= lo < hi <= 1.0:
        raise EvaluationError(f"--interval must satisfy 0 <= LO < HI <= 1 (or percent up to 100), got {values[0]:g} {values[1]:g}")
    return lo, hi


def _options(args: argparse.Namespace) -> tuple[dict, ReducerSpec | None]:
    """Evaluation keyword arguments (the catalogue entry with --reducer, overridden by explicit options) and the
    catalogue entry (None without --reducer)."""
    options: dict = {"lost_motion_pct": 3.0}
    spec = None
    if args.reducer is not None:
        from tcms_daq.config import get_reducer, load_reducer_catalogue
        from tcms_daq.procedure.evaluation import catalogue_options

        spec = get_reducer(load_reducer_catalogue(args.catalogue), args.reducer, args.catalogue)
        options.update(catalogue_options(spec))
    elif args.rated_torque is None:
        raise EvaluationError("give the rated torque (--rated-torque NM) or a catalogue reducer (--reducer NAME)")
    if args.rated_torque is not None:
        options["rated_torque_nm"] = args.rated_torque
    if args.lost_motion_pct is not None:
        options["lost_motion_pct"] = args.lost_motion_pct
    if args.hd_breakpoints:
        options["hd_breakpoints_nm"] = tuple(args.hd_breakpoints)
    options.update(
        test_torque_nm=args.test_torque,
        rigidity_interval=_interval(tuple(args.interval)),
        skip_loops=args.skip_loops,
    )
    return options, spec


def run(args: argparse.Namespace) -> int:
    from tcms_daq.config import load_chain_uncertainty
    from tcms_daq.procedure.evaluation import evaluate_test

    options, spec = _options(args)
    limits = options.pop("limits", None)
    settings = EvaluationSettings(**options)
    chain = load_chain_uncertainty(args.uncertainty) if args.uncertainty is not None else None
    if chain is not None and not chain.declared():
        chain = None  # every declared u is 0: the budget is Type A only, and says so
    samples = read_csv(args.file)
    ev = evaluate_test(samples.time_s, samples.torque_nm, samples.angle_arcsec, settings, limits=limits, chain=chain,
                       rule=args.decision_rule, reducer=spec,
                       no_chain_basis="type A only (no --uncertainty file)" if args.uncertainty is None else
                       f"type A only ({args.uncertainty} declares no nonzero uncertainty)")
    if args.json:
        print(json.dumps({"file": str(args.file), "reducer": args.reducer, **ev.to_dict()}, allow_nan=False))
    else:
        reducer = f", reducer {args.reducer}" if args.reducer else ""
        print(f"{args.file}: {ev.n_samples} samples over {ev.duration_s:.1f} s{reducer}")
        print(format_evaluation(ev))
    return 0

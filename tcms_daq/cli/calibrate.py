"""``tcms calibrate FILE.csv [--terms offset,scale,...] [--model OUT.toml] [--json]``: fit correction terms to
paired encoder/reference readings (columns torque_nm, encoder_arcsec, reference_arcsec [, time_s])."""

from __future__ import annotations

import argparse
import json

from tcms_daq.compensation.calibration import (
    DEFAULT_TERMS,
    calibrate,
    format_calibration,
    read_calibration_csv,
)
from tcms_daq.compensation.terms import parse_term_spec
from tcms_daq.errors import TcmsError


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "calibrate",
        help="fit compensation terms against a reference instrument",
        description="Least-squares fit of compensation terms to a calibration CSV (torque_nm, encoder_arcsec, "
        "reference_arcsec, optional time_s); coefficients with expanded uncertainty U (95 %%, residual "
        "autocorrelation and the reference's declared uncertainty), in-sample and held-out (blocked, leave-one-out) "
        "error.",
    )
    p.add_argument("csv", help="calibration CSV")
    p.add_argument(
        "--terms",
        default=",".join(DEFAULT_TERMS),
        help="comma-separated terms: offset, scale, torsion, drift, periodic:PERIOD_ARCSEC (default offset,scale)",
    )
    p.add_argument("--model", metavar="OUT.toml", help="write the fitted compensator to this TOML file")
    p.add_argument("--cv", choices=("auto", "loo", "blocked"), default="auto",
                   help="held-out error reported as cv_* (the headline): blocked (contiguous blocks; auto is blocked: "
                   "rows are a series in the order measured) or loo")
    p.add_argument("--blocks", type=int, default=5, help="number of contiguous blocks for blocked CV (default 5)")
    p.add_argument("--uncertainty", metavar="FILE.toml", default=None,
                   help="declared standard uncertainty (k = 1) of the reference instrument: a [reference] table with "
                   "u_arcsec (a common offset of its readings) and u_rel (its scale); without it the coefficients' "
                   "U rests on the residuals alone")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    specs = [s for s in (x.strip() for x in args.terms.split(",")) if s]
    if not specs:
        raise TcmsError("--terms is empty")
    terms = [parse_term_spec(s) for s in specs]  # unknown names fail before the file is read
    if args.blocks < 2:
        raise TcmsError("--blocks must be >= 2")
    reference = None
    if args.uncertainty is not None:
        from tcms_daq.config import load_chain_uncertainty

        reference = load_chain_uncertainty(args.uncertainty).reference
    data = read_calibration_csv(args.csv)
    result = calibrate(data, terms, blocks=args.blocks, cv=args.cv, reference=reference)
    if args.model:
        try:
            result.compensator.save(args.model)
        except OSError as exc:
            raise TcmsError(f"{args.model}: cannot write ({exc.strerror or exc})") from None
    if args.json:
        d = result.to_dict()
        if args.model:
            d["model"] = args.model
        print(json.dumps(d, indent=2))
    else:
        print(format_calibration(result))
        if args.model:
            print(f"compensator written to {args.model}")
    return 0

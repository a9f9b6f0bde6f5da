"""``tcms examples [DIR]``: write the example input files the README's quick tour uses.

* ``cal.csv`` — the paper's Table 4 (torque_nm, encoder_arcsec, reference_arcsec): a calibration against the
  autocollimator, for ``tcms calibrate``.
* ``measured.csv`` and ``simulated.csv`` — a simulated RV-110E measurement with a hidden 1 % encoder scale
  error and the reducer model re-simulated on its torque, for ``tcms discrepancy`` (which should name
  ``scale_error``, ratio ≈ 0.01).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from tcms_daq.errors import DataFormatError

SEED = 100


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from tcms_daq.compensation.calibration import CALIBRATION_COLUMNS
    from tcms_daq.compensation.table4 import load_table4
    from tcms_daq.discrepancy.effects import SCALE_ERROR
    from tcms_daq.samples import write_csv
    from tcms_daq.sim.trials import make_pair

    out = Path(args.dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise DataFormatError(f"{out}: cannot create the directory ({exc.strerror or exc})") from None
    t4 = load_table4()
    columns = {"torque_nm": t4.torque_nm, "encoder_arcsec": t4.encoder_arcsec, "reference_arcsec": t4.reference_arcsec}
    rows = np.column_stack([columns[c] for c in CALIBRATION_COLUMNS])
    np.savetxt(out / "cal.csv", rows, delimiter=",", header=",".join(CALIBRATION_COLUMNS), comments="", fmt="%.6g")
    measured, simulated, _ = make_pair({SCALE_ERROR: {"ratio": 0.01}}, SEED)  # a hidden 1 % scale error
    write_csv(out / "measured.csv", measured)
    write_csv(out / "simulated.csv", simulated)
    for name, what in (("cal.csv", "the paper's Table 4: torque, encoder and autocollimator angles"),
                       ("measured.csv", "a simulated RV-110E run with a hidden 1 % encoder scale error"),
                       ("simulated.csv", "the reducer model on the same torque trace, without the effect")):
        print(f"wrote {out / name}: {what}")
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("examples", help="write the quick tour's example input files",
                              description=__doc__.split("\n\n")[0].replace("``", ""))
    p.add_argument("dir", nargs="?", default=".", metavar="DIR", help="where to write them (default: here)")
    p.set_defaults(func=run)

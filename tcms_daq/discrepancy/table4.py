"""The paper's Table 4 through the discrepancy workflow (numbers quoted in docs/discrepancy.md).

measured = the autocollimator column, simulated = the encoder compensated by the paper's model (its "After
Compensation" column). 35 torque steps 0…1700 N·m, loading only, no time stamps: the groups are contiguous
blocks, time-dependent and direction-odd effects are not candidates.

    tcms discrepancy --table4 [--json] [--out DIR]
"""

from __future__ import annotations

import numpy as np

from tcms_daq.samples import Samples


def table4_pair(simulated_column: str = "paper_compensated_arcsec") -> tuple[Samples, Samples]:
    """(measured, simulated) Samples of Table 4 (time_s is the row index; the data carry no time).

    ``simulated_column``: "paper_compensated_arcsec" (the paper's model) or "encoder_arcsec" (no model).
    """
    from tcms_daq.compensation.table4 import load_table4

    t4 = load_table4()
    index = np.arange(len(t4.torque_nm), dtype=float)
    measured = Samples(index, t4.torque_nm, t4.reference_arcsec, {"encoder_arcsec": t4.encoder_arcsec})
    simulated = Samples(index, t4.torque_nm, getattr(t4, simulated_column), {"encoder_arcsec": t4.encoder_arcsec})
    return measured, simulated


def run_table4(signal_period_arcsec: float = 72.0, simulated_column: str = "paper_compensated_arcsec"):
    from tcms_daq.discrepancy.workflow import run_discrepancy

    measured, simulated = table4_pair(simulated_column)
    return run_discrepancy(measured, simulated, signal_period_arcsec=signal_period_arcsec, has_time=False)


def fixed_model_cv(names: list[str]) -> float:
    """Blocked-CV RMS (″) of a fixed set of effects on Table 4 (for the write-up's comparison table)."""
    from tcms_daq.discrepancy.design import build_design
    from tcms_daq.discrepancy.selection import Columns, cv_score, make_folds

    measured, simulated = table4_pair()
    data = build_design(measured, simulated, has_time=False)
    cols = Columns(data)
    rows = np.arange(len(data))
    return cv_score(cols, data.residual_arcsec, make_folds(rows, data.groups), names).rms

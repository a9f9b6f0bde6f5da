"""Evaluating a stiffness test against its reducer's catalogue entry.

The one place that maps a catalogue entry (rated torque, lost-motion level, Harmonic Drive breakpoints,
pass/fail limits) onto ``tcms_daq.analysis.evaluate``; ``tcms run``, ``tcms analyze --reducer`` and the service
all call it.
"""

from __future__ import annotations

from typing import Any

from tcms_daq.analysis import Evaluation, Limits, evaluate
from tcms_daq.config import ReducerSpec
from tcms_daq.samples import Samples


def catalogue_options(reducer: ReducerSpec, test_torque_nm: float | None = None) -> dict[str, Any]:
    """``evaluate`` keyword arguments from a catalogue entry (limits for a test at ``test_torque_nm``, default
    the rated torque)."""
    return {
        "rated_torque_nm": reducer.rated_torque_nm,
        "lost_motion_pct": reducer.lost_motion_pct,
        "hd_breakpoints_nm": reducer.hd_breakpoints_nm,
        "limits": Limits(**reducer.limits(test_torque_nm)),
    }


def evaluate_for_reducer(samples: Samples, reducer: ReducerSpec, test_torque_nm: float | None = None) -> Evaluation:
    """Evaluate the evaluated loops of a test (conditioning already removed) against ``reducer``'s entry."""
    return evaluate(samples.time_s, samples.torque_nm, samples.angle_arcsec, test_torque_nm=test_torque_nm,
                    **catalogue_options(reducer, test_torque_nm))

"""Hysteresis evaluation of torsional characteristic tests: pure functions on sample arrays.

``evaluate(time_s, torque_nm, angle_arcsec, rated_torque_nm=…)`` → ``Evaluation`` (``.to_dict()`` is the JSON
form); ``format_evaluation`` renders it as a table; ``Limits`` carries a reducer's acceptance limits.
"""

from tcms_daq.analysis.evaluation import DirectionResult, Evaluation, Limits, LoopResult, evaluate
from tcms_daq.analysis.harmonic import hd_torsion_angle_rad
from tcms_daq.analysis.report import format_evaluation

__all__ = [
    "DirectionResult",
    "Evaluation",
    "Limits",
    "LoopResult",
    "evaluate",
    "format_evaluation",
    "hd_torsion_angle_rad",
]

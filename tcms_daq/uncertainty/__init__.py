"""Measurement uncertainty (JCGM 100 / GUM, cross-checked by JCGM 101 Monte Carlo): pure functions.

``evaluation_budgets(time_s, torque_nm, angle_arcsec, settings, chain)`` → a :class:`Budget` per result of the
hysteresis evaluation (Type A from the loops, Type B from the declared chain, sensitivities through the
evaluation itself, Welch–Satterthwaite, t-based k for 95 %); ``monte_carlo`` is the JCGM 101 cross-check;
``tcms_daq.uncertainty.regression`` gives least-squares fits (calibration) their uncertainty with correlated
residuals. The arithmetic of the combination is GTC's (the GUM Tree Calculator): docs/uncertainty.md says why.
"""

from tcms_daq.uncertainty.budget import (
    RESULT_UNITS,
    Budget,
    BudgetLine,
    attach,
    evaluation_budgets,
    expanded_by_quantity,
    result_values,
)
from tcms_daq.uncertainty.chain import Input, chain_inputs
from tcms_daq.uncertainty.montecarlo import MonteCarloResult, monte_carlo

__all__ = [
    "RESULT_UNITS",
    "Budget",
    "BudgetLine",
    "Input",
    "MonteCarloResult",
    "attach",
    "chain_inputs",
    "evaluation_budgets",
    "expanded_by_quantity",
    "monte_carlo",
    "result_values",
]

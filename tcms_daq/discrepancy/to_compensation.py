"""From the bench model to the compensator: the accepted effects that are errors of the measuring chain, as
compensator terms (a separate, explicit step with its own compensation version).

The discrepancy model adds a term to the *simulated* angle (measured ≈ simulated + term); the compensator
subtracts a term from the *raw* reading (θ_c = θ − Σ term). An effect of the measuring chain that is a function of
(θ, T) therefore becomes the same term in the compensator. Exact enough (to second order in the effect) are:

* ``scale_error`` s·θ_sim → ``scale`` (coefficient s): s·θ_raw differs by s·(θ_raw − θ_sim);
* ``torsion_offset`` c·T → ``torsion`` (arcsec_per_nm c).

The others stay in the bench model, with the reason: ``thermal_drift`` (the compensator's drift term sees the
bench's absolute clock, the workflow's drift runs from each run's start), the periodic errors (functions of the
compensated angle, the compensator sees the raw reading: re-identify them with ``tcms calibrate`` against a
reference), and everything that needs the trace (``time_skew``, ``backlash``, ``torque_zero_offset``) or is a
property of the reducer, not of the chain (``bending_deformation``, ``nonlinear_stiffness``) or declared by a
user.
"""

from __future__ import annotations

from tcms_daq.compensation.terms import Scale, Term, Torsion
from tcms_daq.discrepancy.model_file import DiscrepancyModel

_LEFT_REASONS = {
    "thermal_drift": "time-dependent: the compensator's drift term sees the bench's absolute clock",
    "interpolation_error": "a function of the compensated angle; re-identify it with tcms calibrate",
    "periodic_error": "a function of the compensated angle; re-identify it with tcms calibrate",
    "time_skew": "needs the torque trace (a time shift), not a function of (θ, T, t)",
    "backlash": "needs the load direction, not a function of (θ, T, t)",
    "torque_zero_offset": "needs the slope along the trace, not a function of (θ, T, t)",
    "bending_deformation": "a property of the reducer and its loading, kept in the bench model",
    "nonlinear_stiffness": "a property of the reducer, kept in the bench model",
}


def compensator_terms(model: DiscrepancyModel) -> tuple[list[Term], dict[str, str]]:
    """(compensator terms for the model's measuring-chain effects, {effect left in the model: why})."""
    terms: list[Term] = []
    left: dict[str, str] = {}
    for term in model.terms:
        if term.name == "scale_error":
            terms.append(Scale(coefficient=term.parameters["ratio"]))
        elif term.name == "torsion_offset":
            terms.append(Torsion(arcsec_per_nm=term.parameters["coef_arcsec_per_nm"]))
        else:
            left[term.name] = _LEFT_REASONS.get(term.name, "a declared effect: kept in the bench model")
    return terms, left

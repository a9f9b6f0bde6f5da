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

from tcms_daq.compensation.terms import Term
from tcms_daq.discrepancy.effects import REGISTRY
from tcms_daq.discrepancy.model_file import DiscrepancyModel


def compensator_terms(model: DiscrepancyModel) -> tuple[list[Term], dict[str, str]]:
    """(compensator terms for the model's measuring-chain effects, {effect left in the model: why})."""
    terms: list[Term] = []
    left: dict[str, str] = {}
    for term in model.terms:
        effect = REGISTRY[term.name]
        if effect.compensator is not None:
            terms.append(effect.compensator(term.parameters))
        else:
            left[term.name] = effect.kept_in_model
    return terms, left

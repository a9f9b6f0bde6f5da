"""Evaluating a stiffness test: the evaluation, its uncertainty budgets, the decision against the limits and the
plausibility checks that need the catalogue.

The one place that maps a catalogue entry (rated torque, lost-motion level, Harmonic Drive breakpoints,
pass/fail limits) onto ``tcms_daq.analysis.evaluate`` and composes it with ``tcms_daq.uncertainty``;
``tcms run``, ``tcms analyze`` and the service all call :func:`evaluate_test` (through
:func:`evaluate_for_reducer` when there is a catalogue entry).
"""

from __future__ import annotations

from dataclasses import asdict
from typing import Any

import numpy.typing as npt

from tcms_daq.analysis import Evaluation, Limits, evaluate
from tcms_daq.analysis.evaluation import EvaluationSettings
from tcms_daq.config import ChainUncertainty, ReducerSpec
from tcms_daq.errors import EvaluationError
from tcms_daq.samples import Samples
from tcms_daq.uncertainty import attach, evaluation_budgets, expanded_by_quantity

FAR_FROM_CATALOGUE = 3.0  # a rigidity more than 3× off the catalogue's is not a reducer deviation
UNIT_MIXUPS = (("degrees", 3600.0), ("radians", 206_264.806), ("arcmin", 60.0))
NO_CHAIN = "type A only (no --uncertainty file)"


def catalogue_options(reducer: ReducerSpec, test_torque_nm: float | None = None) -> dict[str, Any]:
    """``evaluate`` keyword arguments from a catalogue entry (limits for a test at ``test_torque_nm``, default
    the rated torque)."""
    return {
        "rated_torque_nm": reducer.rated_torque_nm,
        "lost_motion_pct": reducer.lost_motion_pct,
        "hd_breakpoints_nm": reducer.hd_breakpoints_nm,
        "limits": Limits(**reducer.limits(test_torque_nm)),
    }


def uncertainty_basis(chain: ChainUncertainty | None, without: str = NO_CHAIN) -> str:
    """What the budgets rest on: "declared chain: <where>" or the Type-A-only wording ``without``."""
    return f"declared chain: {chain.source or 'declared'}" if chain is not None else without


def evaluate_test(time_s: npt.ArrayLike, torque_nm: npt.ArrayLike, angle_arcsec: npt.ArrayLike,
                  settings: EvaluationSettings, *, limits: Limits | None = None,
                  chain: ChainUncertainty | None = None, rule: str = "guarded", reducer: ReducerSpec | None = None,
                  no_chain_basis: str = NO_CHAIN) -> Evaluation:
    """Evaluate a record, attach the uncertainty budget of every result, judge the limits (ISO 14253-1 rule
    ``rule``: "simple" or "guarded") and add the catalogue plausibility warnings (with ``reducer``).

    A budget that cannot be evaluated (a declared uncertainty so large that a perturbed record no longer
    evaluates) leaves ``uncertainty`` empty with a warning saying why; the evaluation itself stands.
    """
    ev = evaluate(time_s, torque_nm, angle_arcsec, **asdict(settings))
    try:
        budgets = evaluation_budgets(time_s, torque_nm, angle_arcsec, settings, chain, nominal=ev)
    except EvaluationError as exc:
        ev.warnings.append(f"uncertainty not evaluated: {exc}")
        ev.uncertainty_basis = uncertainty_basis(chain, no_chain_basis)
    else:
        attach(ev, budgets, uncertainty_basis(chain, no_chain_basis))
    if limits is not None:
        means = {"rigidity_nm_per_arcmin": ev.rigidity_nm_per_arcmin, "backlash_arcsec": ev.backlash_arcsec,
                 "lost_motion_arcsec": ev.lost_motion_arcsec}
        ev.verdict = limits.judge(means, expanded_by_quantity(ev), rule)
    if reducer is not None:
        ev.warnings.extend(catalogue_warnings(ev, reducer))
    return ev


def catalogue_warnings(ev: Evaluation, reducer: ReducerSpec) -> list[str]:
    """A rigidity far outside the catalogue's (more than FAR_FROM_CATALOGUE× off), with the unit mix-up it looks
    like when it is one."""
    expected = reducer.expected_rigidity_nm_per_arcmin(ev.test_torque_nm, ev.rigidity_interval)
    measured = ev.rigidity_nm_per_arcmin
    ratio = measured / expected
    if 1.0 / FAR_FROM_CATALOGUE <= ratio <= FAR_FROM_CATALOGUE:
        return []
    message = (f"rigidity {measured:.4g} N·m/arcmin is {ratio:.3g} × the catalogue's {expected:.4g} N·m/arcmin of "
               f"{reducer.name}")
    for unit, factor in UNIT_MIXUPS:
        if factor / 1.5 <= ratio <= factor * 1.5:
            message += f": as if the angle were in {unit} (× {factor:g}), not arcsec"
            break
    return [message]


def evaluate_for_reducer(samples: Samples, reducer: ReducerSpec, test_torque_nm: float | None = None, *,
                         chain: ChainUncertainty | None = None, rule: str = "guarded",
                         no_chain_basis: str = NO_CHAIN) -> Evaluation:
    """Evaluate the evaluated loops of a test (conditioning already removed) against ``reducer``'s entry."""
    options = catalogue_options(reducer, test_torque_nm)
    limits = options.pop("limits")
    settings = EvaluationSettings(test_torque_nm=test_torque_nm, **options)
    return evaluate_test(samples.time_s, samples.torque_nm, samples.angle_arcsec, settings, limits=limits,
                         chain=chain, rule=rule, reducer=reducer, no_chain_basis=no_chain_basis)

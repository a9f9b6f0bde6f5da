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

import numpy as np
import numpy.typing as npt

from tcms_daq.analysis import Evaluation, Limits, evaluate
from tcms_daq.analysis.evaluation import EvaluationSettings, decision_of, overall_decision
from tcms_daq.analysis.notices import Notice, notices_in
from tcms_daq.config import ChainUncertainty, ReducerSpec
from tcms_daq.errors import DataFormatError, EvaluationError
from tcms_daq.samples import Samples
from tcms_daq.uncertainty import attach, evaluation_budgets, expanded_by_quantity

FAR_FROM_CATALOGUE = 3.0  # a rigidity more than 3× off the catalogue's is not a reducer deviation
UNIT_MIXUPS = (("degrees", 3600.0), ("radians", 206_264.806), ("arcmin", 60.0))
NO_CHAIN = "type A only (no --uncertainty file)"
UNIT_MIXUP_TEXT = "as if the angle were in"


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
    """Evaluate a record, attach the uncertainty budget of every result, add the catalogue plausibility warnings
    (with ``reducer``) and judge the limits (ISO 14253-1 rule ``rule``: "simple" or "guarded"; "undecided" with
    the reasons when the record cannot be judged: ``Evaluation.undecidable``, a unit mix-up against the catalogue).

    A budget that cannot be evaluated (a declared uncertainty so large that a perturbed record no longer
    evaluates) leaves ``uncertainty`` empty with a warning saying why; the evaluation itself stands.
    """
    ev = evaluate(time_s, torque_nm, angle_arcsec, **asdict(settings))
    try:
        budgets = evaluation_budgets(time_s, torque_nm, angle_arcsec, settings, chain, nominal=ev)
    except EvaluationError as exc:
        ev.warnings.append(Notice("uncertainty_not_evaluated", "uncertainty not evaluated: {error}", error=str(exc)))
        ev.uncertainty_basis = uncertainty_basis(chain, no_chain_basis)
    else:
        attach(ev, budgets, uncertainty_basis(chain, no_chain_basis))
    if reducer is not None:
        found = catalogue_warnings(ev, reducer)
        ev.warnings.extend(found)
        # a rigidity off by the factor of a unit mix-up: the angle column is not in arcsec, nothing can be judged
        ev.undecidable.extend(w for w in found if UNIT_MIXUP_TEXT in w)
    if limits is not None:
        means = {"rigidity_nm_per_arcmin": ev.rigidity_nm_per_arcmin, "backlash_arcsec": ev.backlash_arcsec,
                 "lost_motion_arcsec": ev.lost_motion_arcsec}
        ev.verdict = limits.judge(means, expanded_by_quantity(ev), rule, refusals=ev.undecidable)
    return ev


def catalogue_warnings(ev: Evaluation, reducer: ReducerSpec) -> list[str]:
    """A rigidity far outside the catalogue's (more than FAR_FROM_CATALOGUE× off), with the unit mix-up it looks
    like when it is one."""
    expected = reducer.expected_rigidity_nm_per_arcmin(ev.test_torque_nm, ev.rigidity_interval)
    measured = ev.rigidity_nm_per_arcmin
    ratio = measured / expected
    if 1.0 / FAR_FROM_CATALOGUE <= ratio <= FAR_FROM_CATALOGUE:
        return []
    params = {"measured": f"{measured:.4g}", "ratio": f"{ratio:.3g}", "expected": f"{expected:.4g}",
              "reducer": reducer.name}
    template = "rigidity {measured} N·m/arcmin is {ratio} × the catalogue's {expected} N·m/arcmin of {reducer}"
    for unit, factor in UNIT_MIXUPS:
        if factor / 1.5 <= ratio <= factor * 1.5:
            return [Notice("rigidity_unit_mixup", template + ": " + UNIT_MIXUP_TEXT + " {unit} (× {factor}), not arcsec",
                           **params, unit=unit, factor=f"{factor:g}")]
    return [Notice("rigidity_far_from_catalogue", template, **params)]


def evaluate_for_reducer(samples: Samples, reducer: ReducerSpec, test_torque_nm: float | None = None, *,
                         chain: ChainUncertainty | None = None, rule: str = "guarded",
                         no_chain_basis: str = NO_CHAIN) -> Evaluation:
    """Evaluate the evaluated loops of a test (conditioning already removed) against ``reducer``'s entry."""
    options = catalogue_options(reducer, test_torque_nm)
    limits = options.pop("limits")
    settings = EvaluationSettings(test_torque_nm=test_torque_nm, **options)
    return evaluate_test(samples.time_s, samples.torque_nm, samples.angle_arcsec, settings, limits=limits,
                         chain=chain, rule=rule, reducer=reducer, no_chain_basis=no_chain_basis)



# -- tests at several positions or rates (tcms_daq.procedure.plan) ----------------------------------------------

#: the summarised results: (key, the worst value is the …) — GB/T 40731 and the catalogues state lost motion as
#: the maximum over the positions; backlash likewise; rigidity as the minimum.
SUMMARY_QUANTITIES = (("rigidity_nm_per_arcmin", "min"), ("lost_motion_arcsec", "max"), ("backlash_arcsec", "max"))
STAGE_KEYS = ("rigidity_nm_per_arcmin", "lost_motion_arcsec", "backlash_arcsec", "loading_rate_nm_per_s",
              "loop_energy_j", "n_loops", "k1_nm_per_rad", "k2_nm_per_rad", "k3_nm_per_rad", "verdict", "warnings",
              "uncertainty")


def stage_entry(result: dict[str, Any], stage: Any) -> dict[str, Any]:
    """The per-position / per-rate entry of a stage's evaluation dict: its position or rate, the main results
    (with their ``uncertainty`` entries when the evaluation has them) and both sides' rigidity."""
    entry: dict[str, Any] = {}
    if stage.position_deg is not None:
        entry["position_deg"] = float(stage.position_deg)
    entry["rate_nm_per_s"] = float(stage.rate_nm_per_s)
    entry.update({k: result[k] for k in STAGE_KEYS if k in result and result[k] is not None})
    for side in ("positive", "negative"):
        direction = (result.get("per_direction") or {}).get(side)
        if direction is not None:
            entry[f"{side}_rigidity_nm_per_arcmin"] = direction["rigidity_nm_per_arcmin"]
    return entry


def rate_sensitivity(rates_nm_per_s: list[float], values: list[float]) -> float | None:
    """d value / d log10(rate): the least-squares slope over the rates, per decade of loading rate (None for
    fewer than two distinct rates)."""
    x = np.log10(np.asarray(rates_nm_per_s, dtype=float))
    y = np.asarray(values, dtype=float)
    if len(set(x.tolist())) < 2:
        return None
    xc = x - x.mean()
    return float(np.dot(xc, y - y.mean()) / np.dot(xc, xc))


def _combined_verdict(results: list[dict[str, Any]], worst: dict[str, int]) -> dict[str, Any] | None:
    """Each check taken from the stage where its quantity is worst; the plan passes when every check does."""
    verdicts: list[dict[str, Any]] = [r["verdict"] for r in results if r.get("verdict") is not None]
    if not verdicts or len(verdicts) != len(results):
        return None
    checks: dict[str, Any] = {}
    for name in verdicts[0].get("checks", {}):
        quantity = verdicts[0]["checks"][name].get("quantity")
        source = worst.get(quantity, 0)
        checks[name] = {**verdicts[source]["checks"][name], "stage": source + 1}
    out: dict[str, Any] = {**verdicts[0], "checks": checks,
                           "passed": all(c.get("passed", False) for c in checks.values())}
    if "decision" in verdicts[0]:
        out["decision"] = overall_decision(decision_of(c) or "fail" for c in checks.values())
        out["passed"] = out["decision"] == "pass"
    return out


def summarise_plan(kind: str, stages: list[Any], results: list[dict[str, Any]]) -> dict[str, Any]:
    """One result dict for a test of several stages: every key of the first stage's evaluation (so consumers of
    a single test keep working), the summary quantities replaced by their worst value over the stages, with
    ``<quantity>_max/_min/_mean/_spread``, ``positions`` or ``rates`` (per-stage entries), the loops of all
    stages (each marked with its ``stage``), and for rates the rate sensitivity."""
    if len(stages) != len(results) or not results:
        raise ValueError("one evaluation per stage is needed")
    out = dict(results[0])
    worst: dict[str, int] = {}
    for key, rule in SUMMARY_QUANTITIES:
        values = [float(r[key]) for r in results]
        pick = int(np.argmin(values) if rule == "min" else np.argmax(values))
        worst[key] = pick
        out[key] = values[pick]
        out[f"{key}_max"], out[f"{key}_min"] = max(values), min(values)
        out[f"{key}_mean"] = float(np.mean(values))
        out[f"{key}_spread"] = max(values) - min(values)
    # the spread over the loops of the stage each summary value comes from
    out["std"] = {**(results[0].get("std") or {}),
                  **{key: (results[i].get("std") or {}).get(key) for key, i in worst.items()}}
    uncertainties = [r.get("uncertainty") or {} for r in results]
    if any(uncertainties):
        out["uncertainty"] = {key: uncertainties[i][key] for key, i in worst.items() if key in uncertainties[i]}
    out["summary_rule"] = "worst over the stages: minimum rigidity, maximum lost motion and backlash"
    verdict = _combined_verdict(results, worst)
    if verdict is not None:
        out["verdict"] = verdict
    out["loops"] = [{**loop, "stage": i + 1} for i, r in enumerate(results) for loop in r.get("loops", [])]
    out["n_loops"] = int(sum(r.get("n_loops", 0) for r in results))
    label = "position" if kind == "positions" else "rate"
    out["warnings"] = [f"{label} {i + 1}: {w}" for i, r in enumerate(results) for w in r.get("warnings", [])]
    out["notices"] = [{**n, "stage": {"kind": label, "number": i + 1}} for i, r in enumerate(results)
                      for n in notices_in(r)]
    entries = [stage_entry(r, s) for r, s in zip(results, stages, strict=True)]
    out["plan"] = kind
    if kind == "positions":
        out["positions"] = entries
    else:
        out["rates"] = entries
        rates = [e["rate_nm_per_s"] for e in entries]
        out["rate_sensitivity"] = {
            f"{key}_per_decade": rate_sensitivity(rates, [float(e[key]) for e in entries])
            for key, _ in SUMMARY_QUANTITIES
        }
        out["rate_sensitivity"]["definition"] = ("d value / d log10(loading rate): change per tenfold loading rate, "
                                                 "in the value's unit (least squares over the rates)")
    return out


def evaluate_plan(samples: Samples, plan: Any, reducer: ReducerSpec, *, chain: ChainUncertainty | None = None,
                  rule: str = "guarded", no_chain_basis: str = NO_CHAIN) -> dict[str, Any]:
    """Evaluate the evaluated loops of a plan's run (``stage_index`` and ``loop_index`` columns), stage by stage
    with :func:`evaluate_for_reducer` (the same call a single test uses: each stage with its uncertainty budget
    and decision), and summarise them."""
    options: dict[str, Any] = {"chain": chain, "rule": rule, "no_chain_basis": no_chain_basis}
    if plan.kind == "single":
        return evaluate_for_reducer(samples, reducer, plan.first.test_torque_nm, **options).to_dict()
    stage_column = samples.extra.get("stage_index")
    if stage_column is None:
        raise DataFormatError("a run of several stages needs the stage_index column")
    loop = samples.extra.get("loop_index")
    results = []
    for stage in plan.stages:
        mask = stage_column == stage.index
        if loop is not None:
            mask &= loop >= 1
        results.append(evaluate_for_reducer(samples.select(mask), reducer, stage.profile.test_torque_nm,
                                            **options).to_dict())
    return summarise_plan(plan.kind, list(plan.stages), results)

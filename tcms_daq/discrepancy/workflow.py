"""The discrepancy workflow: residual → localisation → identifiability → selection → model → re-simulation.

:func:`run_discrepancy` is the one entry point (CLI, service, trials). Steps (DESIGN §8):

0. The simulation is put onto the measured rows (``pairing``: same rows, its own time grid, or another torque
   compared at equal torque).
1. r = measured − simulated on aligned rows; baseline: RMS/max of r and the blocked-CV RMS of the
   offset-only model (groups: runs, else loops between torque minima, else contiguous blocks).
2. Localisation of r (``localise``).
3. Candidates: every catalogue effect that is identifiable in this design at all (e.g. no ``backlash``
   without load reversals, no time terms without ``time_s``).
4. Forward selection by leave-one-group-out CV with the 1-SE rule; look-alike candidates (within one SE and
   strongly correlated) form an alias group reported with the experiment that would separate them.
5. The whole selection is repeated inside every outer fold (nested CV): its held-out RMS is the reported
   error after the workflow, and how often each effect is selected there is its stability; an effect
   selected in fewer than 80 % of the outer folds is not accepted.
6. Accepted effects are fitted on all rows and added to the simulation; the re-simulated angle is compared
   again (RMS, max, per load direction).
7. The verdict (``verdict``): is what remains noise, judged against a noise floor estimated without the model?
   ``consistent`` / ``explained`` / ``partially_explained`` / ``unexplained``; when structure remains, where it
   is and what shape it has, and the names are provisional.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from threadpoolctl import threadpool_limits

from tcms_daq.discrepancy import catalogue as cat
from tcms_daq.discrepancy.design import DesignData, build_design
from tcms_daq.discrepancy.identifiability import cancelling_pairs, resolve
from tcms_daq.discrepancy.localise import localise
from tcms_daq.discrepancy.pairing import Pairing, pair
from tcms_daq.discrepancy.selection import Columns, cv_score, fit_model, make_folds, nested_cv, select
from tcms_daq.discrepancy.verdict import Verdict, judge
from tcms_daq.samples import Samples

STABILITY = 0.8
SIGNIFICANCE = 2.0  # a named parameter is identified when |value| ≥ 2 u (jackknife, k = 1)
# the expanded uncertainty U = k·u covers about 95 % (as tcms_daq.uncertainty.budget.COVERAGE_PROBABILITY), k from
# Student's t for the jackknife's g − 1 degrees of freedom
EXPANDED_COVERAGE = 0.95


@dataclass
class NamedEffect:
    name: str
    parameters: dict[str, float]
    cv_rms_before_arcsec: float
    cv_rms_after_arcsec: float
    inclusion: float  # share of outer folds whose selection included it
    standard_uncertainty: dict[str, float] = field(default_factory=dict)  # k = 1, jackknife over the groups
    degrees_of_freedom: int | None = None  # of u: the jackknife's groups g − 1 (None: no estimate)

    @property
    def coverage_factor(self) -> float | None:
        """k of the expanded uncertainty (about 95 %): Student's t for ``degrees_of_freedom``."""
        return coverage_factor(self.degrees_of_freedom)

    @property
    def expanded_uncertainty(self) -> dict[str, float]:
        """U = k·u of every parameter (about 95 %, :data:`EXPANDED_COVERAGE`); empty without u."""
        k = self.coverage_factor
        return {key: k * u for key, u in self.standard_uncertainty.items()} if k is not None else {}

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "parameters": dict(self.parameters),
            "standard_uncertainty": dict(self.standard_uncertainty),
            "degrees_of_freedom": self.degrees_of_freedom,
            "coverage_factor": self.coverage_factor,
            "expanded_uncertainty": self.expanded_uncertainty,
            "cv_rms_before_arcsec": self.cv_rms_before_arcsec,
            "cv_rms_after_arcsec": self.cv_rms_after_arcsec,
            "inclusion": self.inclusion,
        }


@dataclass
class AliasGroup:
    names: list[str]
    separating_experiment: str
    representative: str  # the member whose form was added to the model (it predicts as well as the others)
    parameters: dict[str, float]
    in_model: bool

    @property
    def separating_run(self) -> str | None:
        """The kind of run that separates the group when a test request can make it (``effects.SECOND_RATE``,
        ``effects.TIP_HOLDS``), else None."""
        return cat.separating_run(self.names)

    def to_dict(self) -> dict[str, Any]:
        return {"names": list(self.names), "separating_experiment": self.separating_experiment,
                "separating_run": self.separating_run, "representative": self.representative,
                "parameters": dict(self.parameters), "in_model": self.in_model}


@dataclass
class DiscrepancyResult:
    """Outcome of the workflow; ``to_dict()`` is the JSON contract (CLI ``--json``, API)."""

    effects: list[NamedEffect]
    aliases: list[AliasGroup]
    rms_before_arcsec: float
    rms_after_arcsec: float
    max_before_arcsec: float
    max_after_arcsec: float
    cv_rms_before_arcsec: float
    cv_rms_after_arcsec: float
    offset_arcsec: float
    model_terms: list[tuple[str, dict[str, float]]]  # (name, parameters) in order, incl. alias representatives
    per_direction: dict[str, dict[str, float]]
    rejected: list[dict[str, str]]
    unavailable: dict[str, str]
    inclusion: dict[str, float]
    localisation: dict[str, Any]
    groups: dict[str, Any]
    signal_period_arcsec: float
    verdict: Verdict
    uncertainties: dict[str, dict[str, float]]  # per model term: standard uncertainty of each parameter (k = 1)
    uncertainty_dof: int | None  # degrees of freedom of every u: the jackknife's groups g − 1 (None: no u)
    fit_range: dict[str, list[float] | None]  # the data the terms were fitted on: time, torque, angle spans
    data: DesignData = field(repr=False)
    residual_before_arcsec: np.ndarray = field(repr=False)
    residual_after_arcsec: np.ndarray = field(repr=False)
    resimulated_angle_arcsec: np.ndarray = field(repr=False)
    held_out_residual_arcsec: np.ndarray = field(repr=False)
    pairing: Pairing | None = field(default=None, repr=False)
    paired: tuple[Samples, Samples] | None = field(default=None, repr=False)  # (measured, simulated) rows used

    @property
    def names(self) -> list[str]:
        return [e.name for e in self.effects]

    @property
    def drift_reference_time_s(self) -> float | None:
        """t0 of the drift term r·(t − t0): the first analysed sample's time (None without time)."""
        return float(self.data.time_s[0]) if self.data.has_time and len(self.data) else None

    def to_dict(self, *, localisation: bool = False) -> dict[str, Any]:
        verdict = self.verdict.to_dict()
        out = {
            "verdict": verdict.pop("verdict"),
            "verdict_words": verdict.pop("words"),
            "verdict_notices": verdict.pop("notices"),
            **verdict,
            "effects": [{**e.to_dict(), "provisional": self.verdict.provisional} for e in self.effects],
            "aliases": [a.to_dict() for a in self.aliases],
            "rms_before_arcsec": self.rms_before_arcsec,
            "rms_after_arcsec": self.rms_after_arcsec,
            "max_before_arcsec": self.max_before_arcsec,
            "max_after_arcsec": self.max_after_arcsec,
            "cv_rms_before_arcsec": self.cv_rms_before_arcsec,
            "cv_rms_after_arcsec": self.cv_rms_after_arcsec,
            "offset_arcsec": self.offset_arcsec,
            "per_direction": self.per_direction,
            "rejected": self.rejected,
            "unavailable": self.unavailable,
            "inclusion": self.inclusion,
            "groups": self.groups,
            "signal_period_arcsec": self.signal_period_arcsec,
            "strongest_signal": self.localisation.get("strongest_signal"),
            "pairing": self.pairing.to_dict() if self.pairing is not None else None,
            "fit_range": self.fit_range,
            "drift_reference_time_s": self.drift_reference_time_s,
        }
        if localisation:
            out["localisation"] = self.localisation
        return out


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x)))) if len(x) else float("nan")


def _per_direction(data: DesignData, before: np.ndarray, after: np.ndarray) -> dict[str, dict[str, float]]:
    out = {}
    for label, mask in (("loading", data.direction > 0), ("unloading", data.direction < 0)):
        if mask.any():
            out[label] = {"samples": int(mask.sum()), "rms_before_arcsec": _rms(before[mask]),
                          "rms_after_arcsec": _rms(after[mask]), "mean_before_arcsec": float(before[mask].mean()),
                          "mean_after_arcsec": float(after[mask].mean())}
    return out


def run_discrepancy(measured: Samples, simulated: Samples, *, signal_period_arcsec: float = 72.0,
                    has_time: bool = True, effects: list[str] | None = None) -> DiscrepancyResult:
    """Compare ``measured`` with ``simulated``, name the missing effects. ``simulated`` may have the measured
    rows, its own time grid (offset in time) or another torque (e.g. the commanded one): see ``pairing``.

    ``has_time=False`` when the data carry no real time stamps (time-dependent effects are then not
    candidates). ``effects`` restricts the candidate catalogue (default: all of it).

    BLAS runs on one thread here: the fits are many small least-squares problems, for which a thread pool costs
    more than it gives and makes the workflow 5–10× slower beside one other busy process.
    """
    with threadpool_limits(limits=1, user_api="blas"):
        measured, simulated, pairing = pair(measured, simulated, has_time=has_time)
        data = build_design(measured, simulated, signal_period_arcsec=signal_period_arcsec, has_time=has_time)
        result = analyse(data, effects)
    result.pairing, result.paired = pairing, (measured, simulated)
    return result


def coverage_factor(dof: int | None, coverage: float = EXPANDED_COVERAGE) -> float | None:
    """k for which ±k·u covers ``coverage`` when u has ``dof`` degrees of freedom (two-sided Student t); None
    without u."""
    if dof is None or dof < 1:
        return None
    from scipy.stats import t

    return float(t.ppf(0.5 + coverage / 2.0, dof))


def jackknife_fits(cols: Columns, y: np.ndarray, groups: np.ndarray, names: list[str]
                   ) -> list[dict[str, dict[str, float]]]:
    """The parameters of ``names`` refitted with each group (run, loop or block) left out, nonlinear values scanned
    again, in the order of ``np.unique(groups)``. Fewer than three groups, or no names: empty."""
    labels = np.unique(groups)
    if not names or len(labels) < 3:
        return []
    rows = np.arange(len(y))
    return [fit_model(cols, y, rows[groups != g], names, rescan=tuple(names)).parameters() for g in labels]


def jackknife_uncertainties(cols: Columns, y: np.ndarray, groups: np.ndarray, names: list[str],
                            params: dict[str, dict[str, float]]) -> dict[str, dict[str, float]]:
    """Standard uncertainty (k = 1) of every parameter of ``names``: the delete-one-group jackknife over the
    groups (runs, loops or blocks), so the serial correlation inside a loop does not make it look smaller.
    Fewer than three groups: no estimate (empty). Each u has g − 1 degrees of freedom: with the few loops of a test
    error/u has Student's tails, not a normal distribution's, and ±2u covers well under 95 % (U = k·u with
    :func:`coverage_factor`). A bias common to every group — a form that differs from the physics, an estimator's
    bias — is not in u (``python -m tcms_daq.sim.coverage``, docs/discrepancy.md).
    """
    fits = jackknife_fits(cols, y, groups, names)
    if not fits:
        return {}
    g = len(fits)
    out: dict[str, dict[str, float]] = {}
    for name in names:
        out[name] = {}
        for key in params[name]:
            values = np.array([f[name][key] for f in fits])
            if key.endswith("_rad"):  # a phase: spread around the full-data value, not across ±π
                values = params[name][key] + np.angle(np.exp(1j * (values - params[name][key])))
            out[name][key] = float(np.sqrt((g - 1) / g * np.sum((values - values.mean()) ** 2)))
    return out


def analyse(data: DesignData, effects: list[str] | None = None) -> DiscrepancyResult:
    y = data.residual_arcsec
    cat.load_entry_point_effects()
    wanted = list(effects) if effects is not None else list(cat.EFFECT_NAMES)
    for name in wanted:
        if name not in cat.CATALOGUE:
            raise KeyError(f"unknown effect {name!r}")
    unavailable: dict[str, str] = {}
    candidates = []
    for name in wanted:
        reason = cat.available(name, data)
        if reason is None:
            candidates.append(name)
        else:
            unavailable[name] = reason
    cols = Columns(data)
    rows = np.arange(len(y))
    sel = select(cols, y, rows, candidates)
    nested = nested_cv(cols, y, candidates)
    rejected = [{"name": k, "reason": v} for k, v in sel.excluded.items()]
    kept_steps = []
    for step in sel.steps[: sel.chosen]:
        members = [step.name, *step.aliases]
        inc = min(1.0, sum(nested.inclusion.get(a, 0.0) for a in members))
        if inc < STABILITY:
            rejected.append({"name": step.name,
                             "reason": f"unstable: selected in {inc:.0%} of the outer folds (< {STABILITY:.0%})"})
            continue
        kept_steps.append(step)
    model_names = [s.name for s in kept_steps]
    final = fit_model(cols, y, rows, model_names, rescan=tuple(model_names))
    params = final.parameters()
    # an implausible value on all rows (it was plausible when selected) drops the term
    for name in list(model_names):
        reason = cat.plausibility(name, params[name], data)
        if reason is not None:
            rejected.append({"name": name, "reason": reason})
            model_names.remove(name)
            kept_steps = [s for s in kept_steps if s.name != name]
    if len(model_names) != len(params):
        final = fit_model(cols, y, rows, model_names, rescan=tuple(model_names))
        params = final.parameters()
    # two terms that cancel are never both named: keep the simpler, or name neither (an alias group)
    cancelled: list[AliasGroup] = []
    folds_all = make_folds(rows, data.groups)
    while pairs := cancelling_pairs(cols, final, rows):
        resolution = resolve(cols, y, folds_all, model_names, pairs[0])
        for name in resolution.drop:
            rejected.append({"name": name, "reason": resolution.reason})
            model_names.remove(name)
        if resolution.keep is None:
            members = list(resolution.cancellation.names)
            cancelled.append(AliasGroup(members, cat.separating_experiment(members), members[0], {}, False))
        kept_steps = [s for s in kept_steps if s.name in model_names]
        final = fit_model(cols, y, rows, model_names, rescan=tuple(model_names))
        params = final.parameters()
    uncertainties = jackknife_uncertainties(cols, y, data.groups, model_names, params)
    n_groups = int(len(np.unique(data.groups)))
    dof = n_groups - 1 if uncertainties else None
    path = sel.path()
    index = {s.name: i for i, s in enumerate(sel.steps)}
    named: list[NamedEffect] = []
    aliases: list[AliasGroup] = []
    for step in kept_steps:
        i = index[step.name]
        if step.aliases:
            members = [step.name, *step.aliases]
            aliases.append(AliasGroup(members, cat.separating_experiment(members), step.name, params[step.name],
                                      True))
        else:
            named.append(NamedEffect(step.name, params[step.name], path[i].rms, path[i + 1].rms,
                                     nested.inclusion.get(step.name, 0.0), uncertainties.get(step.name, {}),
                                     dof if step.name in uncertainties else None))
    aliases.extend(cancelled)
    # aliases among candidates that were not accepted are still worth reporting when they tied at a step
    for step in sel.steps[sel.chosen:]:
        if step.aliases:
            members = [step.name, *step.aliases]
            aliases.append(AliasGroup(members, cat.separating_experiment(members), step.name, {}, False))
    fitted = final.predict(cols, rows)
    after = y - fitted
    not_identified = {n: why for n in model_names if (why := cat.identification_limit(n, params[n], data))}
    for n in model_names:  # a named size must stand out of its own uncertainty
        primary = cat.CATALOGUE[n].primary
        u = uncertainties.get(n, {}).get(primary)
        if n not in not_identified and u is not None and abs(params[n][primary]) < SIGNIFICANCE * u:
            not_identified[n] = (f"{primary} = {params[n][primary]:.3g} is within {SIGNIFICANCE:g} standard "
                                 f"uncertainties ({u:.2g}) of zero")
    identified = [n for n in model_names if n not in not_identified]
    after_identified = (y - fit_model(cols, y, rows, identified, rescan=tuple(identified)).predict(cols, rows)
                        if not_identified else after)
    if not model_names:
        cv_after = sel.base.rms
    elif model_names == sel.names:
        cv_after = nested.rms
    else:
        cv_after = cv_score(cols, y, make_folds(rows, data.groups), model_names).rms
    return DiscrepancyResult(
        effects=named,
        aliases=aliases,
        rms_before_arcsec=_rms(y),
        rms_after_arcsec=_rms(after),
        max_before_arcsec=float(np.max(np.abs(y))),
        max_after_arcsec=float(np.max(np.abs(after))),
        cv_rms_before_arcsec=sel.base.rms,
        cv_rms_after_arcsec=float(cv_after),
        offset_arcsec=final.offset_arcsec,
        model_terms=[(n, params[n]) for n in model_names],
        per_direction=_per_direction(data, y, after),
        rejected=rejected,
        unavailable=unavailable,
        inclusion={k: float(v) for k, v in nested.inclusion.items()},
        localisation=localise(data, y),
        groups={"kind": data.group_kind, "count": n_groups,
                "nested_selections": [list(n) for n in nested.fold_names]},
        signal_period_arcsec=data.signal_period_arcsec,
        verdict=judge(data, y, after, any_named=bool(model_names), not_identified=not_identified,
                      after_identified=after_identified),
        uncertainties=uncertainties,
        uncertainty_dof=dof,
        fit_range={"time_s": [float(data.time_s[0]), float(data.time_s[-1])] if data.has_time else None,
                   "torque_nm": [float(data.torque_nm.min()), float(data.torque_nm.max())],
                   "angle_arcsec": [float(data.sim_angle_arcsec.min()), float(data.sim_angle_arcsec.max())]},
        data=data,
        residual_before_arcsec=y,
        residual_after_arcsec=after,
        resimulated_angle_arcsec=data.sim_angle_arcsec + fitted,
        held_out_residual_arcsec=nested.residual,
    )


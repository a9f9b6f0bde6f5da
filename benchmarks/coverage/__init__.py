"""Coverage of the stated U on validation families the evaluation was not built on (issue 23 item 2).

Each family (``benchmarks.coverage.families``) draws per run a reducer from physics (``benchmarks.coverage.physics``:
Dahl, Prandtl–Ishlinskii play, Bouc–Wen or LuGre-like friction, soft or hard lost-motion zone, asymmetric
stiffness, RV or harmonic-drive size), a profile (continuous or stepped, with or without tip holds, 50 Hz to
10 kHz), the chain's gain errors from the declared standard uncertainties and noise from 0 to 3× the declared.
Every run goes through what ``tcms analyze --uncertainty chain.toml`` does (``evaluate_test`` with the chain file
read by ``load_chain_uncertainty``; the test torque inferred from the record as with ``--reducer``). Per family and
quantity: bias (mean error), its standard error, scatter, coverage (share of runs with |error| ≤ U), median U and
the U that 95 % coverage needs (the 95th percentile of |error|).

``python -m benchmarks.coverage [--runs N] [--seed S] [--only FAMILY …] [--markdown]`` prints the table;
``python -m benchmarks --only coverage`` records it in benchmarks/results.json.
"""

from __future__ import annotations

import math
import tempfile
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from benchmarks.coverage.families import CHAIN_TOML, FAMILIES, LOST_MOTION_PCT, Family, draw
from benchmarks.coverage.physics import Record, Reducer
from tcms_daq.analysis.evaluation import EvaluationSettings, evaluate
from tcms_daq.config.loader import load_chain_uncertainty
from tcms_daq.config.models import ChainUncertainty
from tcms_daq.errors import EvaluationError
from tcms_daq.procedure.evaluation import evaluate_test
from tcms_daq.uncertainty import result_values
from tcms_daq.uncertainty.budget import LOOPS_LINE

QUANTITIES = ("rigidity_nm_per_arcmin", "lost_motion_arcsec", "backlash_arcsec")
SHORT = {"rigidity_nm_per_arcmin": "rigidity", "lost_motion_arcsec": "lost motion", "backlash_arcsec": "backlash"}
UNITS = {"rigidity_nm_per_arcmin": "N·m/arcmin", "lost_motion_arcsec": "″", "backlash_arcsec": "″"}
RUNS = 200
SEED = 23


def declared_chain() -> ChainUncertainty:
    """The validation chain as ``tcms analyze --uncertainty`` reads it (the TOML file, through the same loader)."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "chain.toml"
        path.write_text(CHAIN_TOML, encoding="utf-8")
        chain = load_chain_uncertainty(path)
    chain.source = "benchmarks/coverage chain (torque u_rel 0.001, angle u_rel 0.0005)"
    return chain


@dataclass
class QuantityStats:
    """Errors (value − truth), stated U and relative errors of one quantity over a family's runs."""

    errors: list[float] = field(default_factory=list)
    expanded: list[float] = field(default_factory=list)
    truth: list[float] = field(default_factory=list)
    loops_alone: list[bool] = field(default_factory=list)  # the Type A line was the loop scatter alone
    # the error left after the chain's gain errors' linear part (error − Σ c_i·x_i: the budget's sensitivities, the
    # run's drawn gains), in the run's U: the noise's and the estimator's own
    beyond_chain: list[float] = field(default_factory=list)

    def summary(self) -> dict[str, float]:
        """Bias (mean error, in the unit and in % of the value), its standard error, the scatter, the coverage, the
        median U, and what 95 % coverage needs. U scales with the value (runs draw reducers of different sizes), so
        the need is judged in units of each run's own U: the 95th percentile f of |error|/U; the U that 95 %
        coverage needs is f·U, so "median U / needed" is 1/f, and "bias / U" the mean of error/U."""
        err, big_u = np.asarray(self.errors), np.asarray(self.expanded)
        n = err.size
        in_u = np.abs(err) / big_u
        f95 = float(np.quantile(in_u, 0.95))
        median_u = float(np.median(big_u))
        return {
            "runs": n,
            "bias": float(err.mean()),
            "bias_se": float(err.std(ddof=1) / math.sqrt(n)) if n > 1 else float("nan"),
            "bias_pct": float(100.0 * np.mean(err / np.asarray(self.truth))),
            "bias_over_U": float(np.mean(err / big_u)),
            "sd": float(err.std(ddof=1)) if n > 1 else float("nan"),
            "coverage": float(np.mean(in_u <= 1.0)),
            "median_U": median_u,
            "U_needed_95": f95 * median_u,
            "U_over_needed": 1.0 / f95 if f95 > 0 else float("inf"),
            "worst_error_in_U": float(np.max(in_u)),
            "loops_alone": float(np.mean(self.loops_alone)) if self.loops_alone else float("nan"),
            "beyond_chain_sd_over_U": float(np.std(self.beyond_chain, ddof=1)) if n > 1 else float("nan"),
            "beyond_chain_max_over_U": float(np.max(np.abs(self.beyond_chain))) if n else float("nan"),
        }


@dataclass
class FamilyResult:
    family: Family
    stats: dict[str, QuantityStats]
    failed: list[str]
    twins: dict[str, QuantityStats] | None = None  # the antithetic twins of the first runs, in the same order

    def summary(self) -> dict[str, dict[str, float]]:
        return {q: s.summary() for q, s in self.stats.items()}

    def paired_bias_over_U(self, quantity: str) -> tuple[float, float]:
        """(mean, standard error) over the twinned runs of the pair's mean error in the run's own U: the errors that
        are linear in the gain errors and the noise cancel in each pair, what is left is the estimator's bias."""
        if not self.twins:
            raise ValueError("run_family(..., twins=N) draws the twins")
        own, twin = self.stats[quantity], self.twins[quantity]
        n = len(twin.errors)
        pairs = 0.5 * (np.asarray(own.errors[:n]) + np.asarray(twin.errors)) / np.asarray(own.expanded[:n])
        return float(pairs.mean()), float(pairs.std(ddof=1) / math.sqrt(pairs.size))


def _evaluated(record: Record, reducer: Reducer, chain: ChainUncertainty, gains: dict[str, float]
               ) -> dict[str, tuple[float, float, bool, float]] | str:
    """(error against the truth, U, whether the Type A line is the loop scatter alone, the error beyond the linear
    part of the drawn ``gains`` (chain input name → relative error) in U) per quantity of one run through
    ``tcms analyze --uncertainty``, or why not."""
    settings = EvaluationSettings(rated_torque_nm=reducer.rated_torque_nm, lost_motion_pct=LOST_MOTION_PCT)
    try:
        ev = evaluate_test(record.time_s, record.torque_nm, record.angle_arcsec, settings, chain=chain)
    except EvaluationError as exc:
        return str(exc)
    missing = [q for q in QUANTITIES if ev.uncertainty.get(q) is None]
    if missing:
        return f"no U for {missing[0]}: {ev.warnings}"
    loops = LOOPS_LINE.format(n=ev.n_loops)
    out = {}
    for q in QUANTITIES:
        entry = ev.uncertainty[q]
        error, expanded = float(entry["value"]) - record.truth[q], float(entry["U"])
        linear = sum(float(line["sensitivity"]) * gains.get(line["source"], 0.0) for line in entry["budget"])
        out[q] = (error, expanded, any(line["source"] == loops for line in entry["budget"]), (error - linear) / expanded)
    return out


def _twin_errors(record: Record, reducer: Reducer) -> dict[str, float] | str:
    """The error against the truth per quantity of a run's antithetic twin: its values only (``evaluate``, what
    ``evaluate_test`` evaluates before the budget), the pair is judged in the run's own U."""
    settings = EvaluationSettings(rated_torque_nm=reducer.rated_torque_nm, lost_motion_pct=LOST_MOTION_PCT)
    try:
        values = result_values(evaluate(record.time_s, record.torque_nm, record.angle_arcsec, **asdict(settings)))
    except EvaluationError as exc:
        return str(exc)
    missing = [q for q in QUANTITIES if q not in values]
    return f"twin: no {missing[0]}" if missing else {q: values[q] - record.truth[q] for q in QUANTITIES}


def run_family(family: Family, runs: int, seed: int = SEED, chain: ChainUncertainty | None = None,
               twins: int = 0) -> FamilyResult:
    """``runs`` runs of one family through the evaluation with its budget; the errors against the truth. The first
    ``twins`` runs are evaluated again as their antithetic twins (``FamilyResult.twins``, U the run's own; such a
    run is kept only when both are evaluated)."""
    chain = chain if chain is not None else declared_chain()
    rng = np.random.default_rng([seed, FAMILIES.index(family) if family in FAMILIES else 99])
    stats = {q: QuantityStats() for q in QUANTITIES}
    twin_stats = {q: QuantityStats() for q in QUANTITIES} if twins > 0 else None
    failed: list[str] = []
    for k in range(runs):
        drawn = draw(family, rng)
        outcome = _evaluated(drawn.readings(), drawn.reducer, chain,
                             {"torque scale": drawn.torque_gain, "angle scale": drawn.angle_gain})
        twin = _twin_errors(drawn.readings(-1.0), drawn.reducer) if k < twins and not isinstance(outcome, str) else {}
        if isinstance(outcome, str) or isinstance(twin, str):
            failed.append(outcome if isinstance(outcome, str) else str(twin))
            continue
        for q, (error, expanded, loops_alone, beyond_chain) in outcome.items():
            stats[q].errors.append(error)
            stats[q].expanded.append(expanded)
            stats[q].truth.append(drawn.truth[q])
            stats[q].loops_alone.append(loops_alone)
            stats[q].beyond_chain.append(beyond_chain)
            if twin_stats is not None and q in twin:
                twin_stats[q].errors.append(twin[q])
                twin_stats[q].expanded.append(expanded)
                twin_stats[q].truth.append(drawn.truth[q])
    return FamilyResult(family, stats, failed, twin_stats)


def markdown_table(results: list[FamilyResult]) -> str:
    """Per family and quantity: bias (and in % of the value), coverage, median U, the U 95 % needs, their ratio, and
    the share of runs whose Type A line is the loop scatter alone (the loops vary beyond the noise, or the record has
    no measured noise)."""
    lines = ["| family | quantity | runs | bias | bias / U | coverage | median U | U needed (95 %) | "
             "U / needed | Type A loops alone |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for res in results:
        for q, s in res.summary().items():
            unit = UNITS[q]
            lines.append(
                f"| {res.family.name} | {SHORT[q]} | {s['runs']} | {s['bias']:+.3g} {unit} ({s['bias_pct']:+.3f} %) | "
                f"{s['bias_over_U']:+.2f} | {100 * s['coverage']:.1f} % | {s['median_U']:.3g} | "
                f"{s['U_needed_95']:.3g} | {s['U_over_needed']:.2f} | {100 * s['loops_alone']:.0f} % |")
    return "\n".join(lines)


def run(quick: bool = False) -> dict:
    """The benchmark harness's entry: every family, RUNS runs each (40 when quick)."""
    runs = 40 if quick else RUNS
    chain = declared_chain()
    results = [run_family(f, runs, SEED, chain) for f in FAMILIES]
    metrics: dict[str, float] = {}
    targets: dict[str, dict] = {}
    for res in results:
        for q, s in res.summary().items():
            key = f"{res.family.name}.{SHORT[q].replace(' ', '_')}"
            metrics[f"{key}.coverage"] = s["coverage"]
            metrics[f"{key}.bias_over_U"] = s["bias_over_U"]
            metrics[f"{key}.U_over_needed"] = s["U_over_needed"]
            targets[f"{key}.coverage"] = {"limit": "0.93–0.99", "met": 0.93 <= s["coverage"] <= 0.99}
            targets[f"{key}.bias_over_U"] = {"limit": "|·| < 1/3", "met": abs(s["bias_over_U"]) < 1 / 3}
            targets[f"{key}.U_over_needed"] = {"limit": "≤ 2", "met": s["U_over_needed"] <= 2.0}
        metrics[f"{res.family.name}.failed_runs"] = len(res.failed)
    return {"name": "coverage", "metrics": metrics, "targets": targets,
            "notes": f"{runs} runs per family, seed {SEED}; families: "
                     + "; ".join(f"{f.name}: {f.describe()}" for f in FAMILIES)}

"""Trials of the transmission-error evaluation and its discrepancy workflow, per family, with rates:
``python -m tcms_daq.sim.station_trials --seeds 20 [--family NAME] [--json]``.

Each trial is one unit: run 1 is compared with the unit's model (which lacks the hidden order), the findings are
applied, run 2 (the same unit, a new recording) is compared with the new model. Families:

* ``sim-rv110e``, ``sim-hfuc32``: the simulator (``sim/transmission.py``) with a hidden harmonic at a component's
  order (RV: the pin ring's 2×, order 78; HD: the flexspline's 2×, order 404), 0.5–2″, any phase;
* ``indep-rv``, ``indep-hd``: the independent generator (``sim/te_independent.py``: its own physics, phase
  convention, quantised encoders, speed ripple in time, latch jitter) with a hidden source at a component's order
  (RV: the pin ring's ellipticity, 78; HD: the circular spline's 2×, 400);
* ``indep-rv-noisy``: as ``indep-rv`` with 10× the output encoder's noise;
* ``indep-rv-foreign``: a hidden order that belongs to no component (non-integer, 5…35 away from any named order);
* ``indep-rv-null``, ``sim-rv110e-null``: nothing hidden.

``--coverage``: the four methods on simulated stations whose instruments carry errors drawn from their declared
uncertainties (the output encoder's graduation at orders 1–2, the input encoder's once-per-turn error at any phase,
the readings' skew, both torque channels' gain and zero): per result the share of stations whose U covers the
simulator's truth, the median U and what 95 % needs; and the transmission error of the independent generator's units
(``indep-rv``, ``indep-hd``: its own instruments and errors, the trials' declared chain) against its own truth.

Rates: ``named`` — run 1 names the hidden order (order within 1 %, amplitude within 10 %, the right component) and
nothing else; ``closed`` — run 2 ``consistent``; ``unexplained`` — (foreign) run 1 reports the order (within 1 %)
without a name and names nothing; ``quiet`` — (null) runs 1 and 2 ``consistent``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from tcms_daq.sim.station import (
    StationSensors,
    efficiency_profile,
    no_load_profile,
    record_speed_run,
    record_torque_run,
    starting_profile,
    te_profile,
)
from tcms_daq.sim.te_independent import HdErrors, Recording, RvErrors, Source, generate
from tcms_daq.sim.transmission import (
    UnitPhysics,
    efficiency_truth,
    no_load_torque_truth,
    starting_torque_truth,
    te_peak_to_peak_truth,
    unit_from_spec,
)

from tcms_daq.config import load_reducer_catalogue
from tcms_daq.config.models import ExtraOrder, StationUncertainty, TorqueUncertainty
from tcms_daq.transmission.kinematics import Teeth, components_at, order_table
from tcms_daq.transmission.te import evaluate_transmission_error
from tcms_daq.transmission.te_model import TeComparison, TeHarmonicTerm, TeModel, apply_findings, compare_te
from tcms_daq.transmission.torque import (
    evaluate_efficiency,
    evaluate_no_load_torque,
    evaluate_starting_torque,
)
from tcms_daq.uncertainty.station import (
    MC_DRAWS,
    efficiency_budgets,
    no_load_torque_budgets,
    standard_normal_draws,
    starting_torque_budgets,
    te_allowance,
    te_budgets,
)
from tcms_daq.units import ARCSEC_PER_REV

# the declared chain of the trials (RON 786 ±2″, its interpolation, a motor encoder's eccentricity, the latch skew)
CHAIN = StationUncertainty(output_encoder_u_arcsec=1.2, output_encoder_high_order_u_arcsec=0.1,
                           input_encoder_u_arcsec=25.0, sync_skew_u_s=1e-4)
RV_TEETH = Teeth("rv", input_gear=10, spur_gear=40, crankshafts=3, cycloid=39, pins=40)
HD_TEETH = Teeth("harmonic", flexspline=200, circular_spline=202)

Record = tuple[np.ndarray, np.ndarray, np.ndarray]


@dataclass(frozen=True)
class Trial:
    """One unit: its model, its hidden order (None: none), whether that order belongs to a component, and a
    recorder of runs (run index → record)."""

    model: TeModel
    teeth: Teeth
    hidden: tuple[float, float, str | None] | None  # (order, amplitude ″, component label)
    record: Callable[[int], Record]


def _compare(trial: Trial, run: int) -> TeComparison:
    t, a_in, a_out = trial.record(run)
    allowance = te_allowance(t, a_in, a_out, ratio=trial.model.ratio, chain=CHAIN)
    return compare_te(t, a_in, a_out, trial.model, teeth=trial.teeth, allowance=allowance)


def _sim_trial(name: str, seed: int, hidden_component: str | None, hidden_order: float | None) -> Trial:
    spec = load_reducer_catalogue()[name]
    base = unit_from_spec(spec)
    rng = np.random.default_rng(seed)
    extra = []
    hidden = None
    if hidden_order is not None:
        amplitude = float(rng.uniform(0.5, 2.0))
        extra = [ExtraOrder(order=hidden_order, amplitude_arcsec=amplitude, phase_deg=float(rng.uniform(0, 360)))]
        hidden = (hidden_order, amplitude, hidden_component)
    unit: UnitPhysics = base.with_extra(extra)
    model = TeModel(base.ratio, tuple(TeHarmonicTerm(h.order_per_output_rev, h.amplitude_arcsec,
                                                     math.degrees(h.phase_rad), h.component, "catalogue")
                                      for h in base.harmonics), name)
    sensors = StationSensors(sample_rate_hz=1000.0, speed_ripple_pct=0.5, sync_skew_s=5e-5,
                             input_encoder_error_arcsec=20.0)

    def record(run: int) -> Record:
        c = record_speed_run(unit, te_profile(2000.0, unit.ratio, 1.15, 0.02 * spec.rated_torque_nm), sensors,
                             seed=1000 * seed + run).columns
        return c["time_s"], c["input_angle_arcsec"], c["output_angle_arcsec"]

    return Trial(model, spec.kinematics.teeth(spec.kind), hidden, record)  # type: ignore[union-attr]


def _indep_trial(kind: str, seed: int, hidden: str | None, noise: float = 0.05) -> Trial:
    rng = np.random.default_rng(seed)
    errors: RvErrors | HdErrors = RvErrors() if kind == "rv" else HdErrors()
    teeth = RV_TEETH if kind == "rv" else HD_TEETH
    amplitude = float(rng.uniform(0.5, 2.0))
    lag = float(rng.uniform(0, 360))
    sources: list[Source] = []
    label: str | None = None
    if hidden == "named":
        order = 78.0 if kind == "rv" else 400.0
        label = "pin_ring 2×" if kind == "rv" else "circular_spline 2×"
        sources = [Source("hidden", order, amplitude, lag, label)]
    elif hidden == "foreign":
        table = order_table(teeth)
        while True:
            order = float(rng.uniform(5.0, 35.0))
            if not components_at(order, 1.0, table):
                break
        sources = [Source("hidden", order, amplitude, lag, None)]
    recording = Recording(output_noise_arcsec=noise)
    unit_seed = 7919 * seed + 1
    probe = generate(errors, sources, recording, seed=0, unit_seed=unit_seed)
    model = TeModel(probe.ratio, tuple(TeHarmonicTerm(s.order, s.amplitude_arcsec, probe.project_phase_deg(s),
                                                      s.component, "design") for s in probe.sources
                                       if s.name != "hidden"))

    def record(run: int) -> Record:
        g = generate(errors, sources, recording, seed=1000 * seed + run, unit_seed=unit_seed)
        return g.time_s, g.input_angle_arcsec, g.output_angle_arcsec

    hidden_truth = (sources[0].order, amplitude, label) if sources else None
    return Trial(model, teeth, hidden_truth, record)


FAMILIES: dict[str, Callable[[int], Trial]] = {
    "sim-rv110e": lambda s: _sim_trial("RV-110E", s, "pin_ring 2×", 78.0),
    "sim-hfuc32": lambda s: _sim_trial("HFUC-32-100", s, "flexspline 2×", 404.0),
    "sim-rv110e-null": lambda s: _sim_trial("RV-110E", s, None, None),
    "indep-rv": lambda s: _indep_trial("rv", s, "named"),
    "indep-hd": lambda s: _indep_trial("hd", s, "named"),
    "indep-rv-noisy": lambda s: _indep_trial("rv", s, "named", noise=0.5),
    "indep-rv-foreign": lambda s: _indep_trial("rv", s, "foreign"),
    "indep-rv-null": lambda s: _indep_trial("rv", s, None),
}


def run_trial(trial: Trial) -> dict[str, Any]:
    """Run 1, apply, run 2; the outcome of each criterion (module docstring)."""
    first = _compare(trial, 1)
    out: dict[str, Any] = {"verdict_1": first.verdict, "gaps_1": [(round(f.line.order_per_output_rev, 3),
                                                                   round(f.line.amplitude_arcsec, 3),
                                                                   f.line.component) for f in first.gaps]}
    if trial.hidden is None:
        second = _compare(TrialWithModel.of(trial, apply_findings(trial.model, first)), 2)
        out.update(verdict_2=second.verdict, quiet=first.verdict == "consistent" and second.verdict == "consistent")
        return out
    order, amplitude, label = trial.hidden
    match = [f for f in first.gaps if abs(f.line.order_per_output_rev - order) <= 0.01 * order]
    others = [f for f in first.gaps if f not in match]
    if label is None:
        out["unexplained"] = (len(match) == 1 and not match[0].named and not first.named)
        out["order_error_pct"] = (100 * (match[0].line.order_per_output_rev - order) / order) if match else None
        return out
    found = match[0] if len(match) == 1 else None
    out["amplitude_error_pct"] = (100 * (found.line.amplitude_arcsec - amplitude) / amplitude) if found else None
    out["named"] = bool(found and label in found.line.components
                        and abs(found.line.amplitude_arcsec - amplitude) <= 0.1 * amplitude and not others)
    second = _compare(TrialWithModel.of(trial, apply_findings(trial.model, first)), 2)
    out.update(verdict_2=second.verdict, closed=second.verdict == "consistent",
               gaps_2=[(round(f.line.order_per_output_rev, 3), round(f.line.amplitude_arcsec, 3)) for f in second.gaps])
    return out


class TrialWithModel:
    """A trial with another model (run 2 against the applied one)."""

    @staticmethod
    def of(trial: Trial, model: TeModel) -> Trial:
        return Trial(model, trial.teeth, trial.hidden, trial.record)


def rates(family: str, seeds: int, first_seed: int = 1) -> dict[str, Any]:
    rows = [run_trial(FAMILIES[family](s)) for s in range(first_seed, first_seed + seeds)]
    out: dict[str, Any] = {"family": family, "trials": len(rows)}
    for key in ("named", "closed", "unexplained", "quiet"):
        values = [r[key] for r in rows if key in r]
        if values:
            out[key] = f"{sum(values)}/{len(values)}"
    errors = [abs(r["amplitude_error_pct"]) for r in rows if r.get("amplitude_error_pct") is not None]
    if errors:
        out["amplitude_error_pct_max"] = round(max(errors), 2)
    failures = [r for r in rows if not all(r.get(k, True) for k in ("named", "closed", "unexplained", "quiet"))]
    out["failures"] = failures[:5]
    return out


# ------------------------------------------------------------------------------------------------- coverage

COVERAGE_CHAIN = StationUncertainty(
    output_encoder_u_arcsec=1.2, output_encoder_high_order_u_arcsec=0.1, input_encoder_u_arcsec=20.0,
    sync_skew_u_s=1e-4, input_torque=TorqueUncertainty(u_rel=5e-4, u_zero_nm=0.002),
    output_torque=TorqueUncertainty(u_rel=3e-4, u_zero_nm=0.05))


def _drawn_sensors(rng: np.random.Generator, chain: StationUncertainty) -> tuple[StationSensors, float]:
    """The station's instruments with errors drawn from their declared uncertainties (one station per seed), and
    the input start angle (the phase of the input encoder's error against the unit)."""
    sigma = chain.output_encoder_u_arcsec / math.sqrt(2.0)
    graduation = tuple(float(x) for x in sigma * rng.standard_normal(4))
    sensors = StationSensors(
        sample_rate_hz=1000.0, speed_ripple_pct=0.5,
        sync_skew_s=float(chain.sync_skew_u_s * rng.standard_normal()),
        input_encoder_error_arcsec=float(math.sqrt(2.0) * chain.input_encoder_u_arcsec * abs(rng.standard_normal())),
        input_encoder_error_phase_rad=float(rng.uniform(0, 2 * math.pi)),
        output_encoder_graduation_arcsec=graduation,  # type: ignore[arg-type]
        input_torque_gain=float(1.0 + chain.input_torque.u_rel * rng.standard_normal()),
        input_torque_offset_nm=float(chain.input_torque.u_zero_nm * rng.standard_normal()),
        output_torque_gain=float(1.0 + chain.output_torque.u_rel * rng.standard_normal()),
        output_torque_offset_nm=float(chain.output_torque.u_zero_nm * rng.standard_normal()))
    return sensors, float(rng.uniform(0, ARCSEC_PER_REV))


def coverage_run(name: str, seed: int, chain: StationUncertainty = COVERAGE_CHAIN) -> dict[str, tuple[float, float]]:
    """One simulated station and unit: every result of the four methods as (error against the truth, U)."""
    spec = load_reducer_catalogue()[name]
    unit = unit_from_spec(spec)
    sim = spec.sim.transmission
    assert sim is not None and spec.kinematics is not None  # unit_from_spec refuses an entry without them
    teeth = spec.kinematics.teeth(spec.kind)
    rng = np.random.default_rng(seed)
    sensors, start = _drawn_sensors(rng, chain)
    c = record_speed_run(unit, te_profile(2000.0, unit.ratio, 1.15, 0.02 * spec.rated_torque_nm), sensors,
                         seed=seed, start_input_angle_arcsec=start).columns
    ev = evaluate_transmission_error(c["time_s"], c["input_angle_arcsec"], c["output_angle_arcsec"], ratio=unit.ratio,
                                     teeth=teeth)
    budgets = te_budgets(c["time_s"], c["input_angle_arcsec"], c["output_angle_arcsec"], ev, chain, teeth=teeth)
    out: dict[str, tuple[float, float]] = _te_errors(
        budgets, ev.per_direction, lambda d: te_peak_to_peak_truth(unit, d.phi_start_rad, d.phi_end_rad),
        [(h.order_per_output_rev, h.component, h.amplitude_arcsec) for h in unit.harmonics])
    c = record_torque_run(unit, starting_profile(1.4 * sim.breakaway_torque_nm, 0.25 * sim.breakaway_torque_nm, 3),
                          sensors, seed=seed).columns
    st = evaluate_starting_torque(c["time_s"], c["input_torque_nm"], c["input_angle_arcsec"])
    for key, b in starting_torque_budgets(c["time_s"], c["input_torque_nm"], c["input_angle_arcsec"], st,
                                          chain).items():
        starting = {"forward": starting_torque_truth(unit, 1.0), "reverse": starting_torque_truth(unit, -1.0)}
        expected = starting.get(key.split("_")[0], max(starting.values()))
        out[key] = (b.value - expected, b.expanded)
    speeds = [500.0, 1500.0, 3000.0]
    c = record_speed_run(unit, no_load_profile(speeds, 1.5), sensors, seed=seed).columns
    nl = evaluate_no_load_torque(c["time_s"], c["input_torque_nm"], c["input_angle_arcsec"], speeds_rpm=speeds)
    for key, b in no_load_torque_budgets(c["time_s"], c["input_torque_nm"], c["input_angle_arcsec"], nl,
                                         chain).items():
        n = float(key.split("@")[1].removesuffix("rpm"))
        fwd, rev = no_load_torque_truth(unit, n, 25.0), no_load_torque_truth(unit, -n, 25.0)
        expected = {"forward": fwd, "reverse": rev}.get(key.split("_")[0], 0.5 * (fwd + rev))
        out[key] = (b.value - expected, b.expanded)
    speed = sim.rated_input_speed_rpm
    c = record_speed_run(unit, efficiency_profile(spec.rated_torque_nm, speed, 2.0), sensors, seed=seed).columns
    ef = evaluate_efficiency(c["time_s"], c["input_torque_nm"], c["input_angle_arcsec"], c["output_torque_nm"],
                             c["output_angle_arcsec"])
    for key, b in efficiency_budgets(c["time_s"], c["input_torque_nm"], c["input_angle_arcsec"],
                                     c["output_torque_nm"], c["output_angle_arcsec"], ef, chain).items():
        sign = 1.0 if key.startswith("forward") else -1.0
        out[key] = (b.value - efficiency_truth(unit, spec.rated_torque_nm, sign * speed, 25.0), b.expanded)
    return out


def coverage_independent(kind: str, seed: int) -> dict[str, tuple[float, float]]:
    """The transmission error of one unit of the independent generator (its errors drawn per seed, and its output
    encoder's error at orders 1–2 drawn from the trials' declared chain) against the generator's own truth, with
    the trials' declared chain: (error, U) per result."""
    errors: RvErrors | HdErrors = RvErrors() if kind == "rv" else HdErrors()
    teeth = RV_TEETH if kind == "rv" else HD_TEETH
    # the output encoder's error at orders 1–2 drawn from the declared chain (u RMS over the revolution: each order's
    # cosine and sine N(0, u²/2)), in the generator's own convention (amplitude, lag)
    c1, s1, c2, s2 = CHAIN.output_encoder_u_arcsec / math.sqrt(2.0) * np.random.default_rng((seed, 12)).standard_normal(4)
    encoder = (math.hypot(c1, s1), math.degrees(math.atan2(s1, c1)), math.hypot(c2, s2), math.degrees(math.atan2(s2, c2)))
    g = generate(errors, None, Recording(output_encoder_error=encoder), seed=seed, unit_seed=seed)
    ev = evaluate_transmission_error(g.time_s, g.input_angle_arcsec, g.output_angle_arcsec, ratio=g.ratio, teeth=teeth)
    budgets = te_budgets(g.time_s, g.input_angle_arcsec, g.output_angle_arcsec, ev, CHAIN, teeth=teeth)

    def truth_pp(d: Any) -> float:
        phi = np.linspace(d.phi_start_rad, d.phi_end_rad, 400_001)
        te = sum(src.amplitude_arcsec * np.sin(src.order * phi + math.radians(g.project_phase_deg(src)))
                 for src in g.sources)
        return float(np.ptp(te))

    return _te_errors(budgets, ev.per_direction, truth_pp,
                      [(src.order, src.component, src.amplitude_arcsec) for src in g.sources])


def _te_errors(budgets: dict[str, Any], per_direction: dict[str, Any], peak_to_peak_truth: Callable[[Any], float],
               lines: list[tuple[float, str | None, float]]) -> dict[str, tuple[float, float]]:
    """(error, U) of each transmission-error result against the truth: a line found at one of ``lines``' orders
    (order per output revolution, component, amplitude ″) against its amplitude; each direction's peak-to-peak
    against ``peak_to_peak_truth`` of that direction's evaluation (its angle span), the larger direction's against
    the larger truth. An order of the unit that was not found is a miss (inf, 0: counted as not covered)."""
    truths = {name: peak_to_peak_truth(d) for name, d in per_direction.items()}
    by_order = {round(order, 3): (component, amplitude) for order, component, amplitude in lines}
    out: dict[str, tuple[float, float]] = {}
    for key, b in budgets.items():
        if key.startswith("te_order_"):
            line = by_order.get(round(float(key.split("_")[2]), 3))
            if line is not None:
                out[f"te_order_{line[0]}"] = (b.value - line[1], b.expanded)
        elif key == "transmission_error_arcsec":
            out[key] = (b.value - max(truths.values()), b.expanded)
        else:
            out[key] = (b.value - truths[key.split("_")[0]], b.expanded)
    for _, component, _ in lines:
        out.setdefault(f"te_order_{component}", (math.inf, 0.0))
    return out


def coverage(name: str, seeds: int, first_seed: int = 1) -> dict[str, dict[str, float]]:
    """Per result: the share of stations whose U covers the truth, the median U and the RMS error (U/2 is what a
    95 % interval of a normal error needs, so median U / (2·RMS error) near 1 is tight, above 1 generous)."""
    if name.startswith("indep-"):
        runs = [coverage_independent(name.removeprefix("indep-"), s) for s in range(first_seed, first_seed + seeds)]
    else:
        runs = [coverage_run(name, s) for s in range(first_seed, first_seed + seeds)]
    out = {}
    for key in runs[0]:
        pairs = [r[key] for r in runs if key in r]
        errors = np.array([e for e, _ in pairs])
        us = np.array([u for _, u in pairs])
        finite = np.isfinite(errors)
        rms = float(np.sqrt(np.mean(errors[finite] ** 2))) if finite.any() else math.nan
        out[key] = {"covered": float(np.mean(np.abs(errors) <= us)), "n": len(pairs),
                    "median_U": float(np.median(us)), "rms_error": rms,
                    "U_over_needed": float(np.median(us) / (1.96 * rms)) if rms > 0 else math.inf}
    return out


# what the split switches off: each drawn instrument error of the transmission-error run in turn
# (the sensors' fields set to none, the budget line that covers it)
SPLIT: dict[str, tuple[dict[str, Any], str]] = {
    "output encoder (orders 1–2)": ({"output_encoder_graduation_arcsec": (0.0, 0.0, 0.0, 0.0)},
                                    "output encoder (orders 1–2)"),
    "skew": ({"sync_skew_s": 0.0}, "synchronisation (skew of the angle readings)"),
    "input encoder": ({"input_encoder_error_arcsec": 0.0}, "input encoder (once per input turn)"),
    "speed ripple": ({"speed_ripple_pct": 0.0}, "speed ripple (resampling onto the angle grid)")}


def te_error_split(name: str, seeds: int, first_seed: int = 1, chain: StationUncertainty = COVERAGE_CHAIN
                   ) -> dict[str, dict[str, float]]:
    """The transmission error's peak-to-peak on the coverage stations (the same draws as ``coverage_run``), per
    result: its error against the truth (mean: the bias; sd), the error over U (mean, sd), the coverage, and for
    each drawn instrument error what the error changes when that one is switched off (mean, RMS), against that
    source's budget line (median contribution)."""
    spec = load_reducer_catalogue()[name]
    unit = unit_from_spec(spec)
    assert spec.kinematics is not None
    teeth = spec.kinematics.teeth(spec.kind)
    keys = ("transmission_error_arcsec", "forward_transmission_error_arcsec", "reverse_transmission_error_arcsec")
    rows: list[dict[str, Any]] = []
    for seed in range(first_seed, first_seed + seeds):
        sensors, start = _drawn_sensors(np.random.default_rng(seed), chain)

        def errors(s: StationSensors, seed: int = seed, start: float = start) -> tuple[dict[str, float], Any, Any]:
            c = record_speed_run(unit, te_profile(2000.0, unit.ratio, 1.15, 0.02 * spec.rated_torque_nm), s,
                                 seed=seed, start_input_angle_arcsec=start).columns
            ev = evaluate_transmission_error(c["time_s"], c["input_angle_arcsec"], c["output_angle_arcsec"],
                                             ratio=unit.ratio, teeth=teeth)
            truth = {d: te_peak_to_peak_truth(unit, x.phi_start_rad, x.phi_end_rad) for d, x in ev.per_direction.items()}
            values = {keys[0]: ev.transmission_error_arcsec - max(truth.values())}
            values.update({f"{d}_transmission_error_arcsec": x.peak_to_peak_arcsec - truth[d]
                           for d, x in ev.per_direction.items()})
            return values, c, ev

        full, c, ev = errors(sensors)
        budgets = te_budgets(c["time_s"], c["input_angle_arcsec"], c["output_angle_arcsec"], ev, chain, teeth=teeth)
        row: dict[str, Any] = {"error": full, "U": {k: budgets[k].expanded for k in keys},
                               "lines": {k: {ln.source: ln.contribution for ln in budgets[k].lines} for k in keys}}
        for source, (change, _) in SPLIT.items():
            off, _, _ = errors(dataclasses.replace(sensors, **change))
            row[source] = {k: full[k] - off[k] for k in keys}
        rows.append(row)
    out: dict[str, dict[str, float]] = {}
    for k in keys:
        e = np.array([r["error"][k] for r in rows])
        u = np.array([r["U"][k] for r in rows])
        stats = {"mean_error": float(e.mean()), "sd_error": float(e.std(ddof=1)),
                 "mean_error_over_U": float(np.mean(e / u)), "sd_error_over_U": float(np.std(e / u, ddof=1)),
                 "covered": float(np.mean(np.abs(e) <= u)), "median_U": float(np.median(u))}
        for source, (_, budget_line) in SPLIT.items():
            d = np.array([r[source][k] for r in rows])
            line = [r["lines"][k].get(budget_line, 0.0) for r in rows]
            stats[f"{source}: mean"] = float(d.mean())
            stats[f"{source}: RMS"] = float(np.sqrt(np.mean(d ** 2)))
            stats[f"{source}: median line"] = float(np.median(line)) if line else 0.0
        out[k] = stats
    return out


def te_encoder_on_lines(name: str, seeds: int, first_seed: int = 1, chain: StationUncertainty = COVERAGE_CHAIN,
                        draws: int = MC_DRAWS, points: int = 20_000) -> dict[str, float]:
    """The output encoder's order-1–2 error alone, on the unit's lines (no record, no fit): per coverage station's
    draw (``_drawn_sensors``) the peak-to-peak of lines + error against the lines' (over one revolution), and the
    RMS change a Monte Carlo of the declared error gives at that measured curve (what the budget's line does, here
    apart from the evaluation): the error's mean and RMS, the median u, the share with |error| ≤ 1.96·u."""
    unit = unit_from_spec(load_reducer_catalogue()[name])
    phi = np.linspace(0.0, 2.0 * math.pi, points, endpoint=False)
    truth = sum(h.amplitude_arcsec * np.sin(h.order_per_output_rev * phi + h.phase_rad) for h in unit.harmonics)
    shapes = np.array([np.cos(phi), np.sin(phi), np.cos(2.0 * phi), np.sin(2.0 * phi)])
    sigma = chain.output_encoder_u_arcsec / math.sqrt(2.0)
    moves = sigma * standard_normal_draws(np.random.default_rng(0), draws, 4) @ shapes
    errors, us = [], []
    for seed in range(first_seed, first_seed + seeds):
        sensors, _ = _drawn_sensors(np.random.default_rng(seed), chain)
        measured = truth + np.array(sensors.output_encoder_graduation_arcsec) @ shapes
        value = float(np.ptp(measured))
        errors.append(value - float(np.ptp(truth)))
        us.append(float(np.sqrt(np.mean((np.ptp(measured[None, :] + moves, axis=1) - value) ** 2))))
    e, u = np.array(errors), np.array(us)
    rms = float(np.sqrt(np.mean(e ** 2)))
    return {"mean_error": float(e.mean()), "rms_error": rms, "median_u": float(np.median(u)),
            "covered": float(np.mean(np.abs(e) <= 1.96 * u)), "U_over_needed": float(np.median(u)) / rms}


COVERAGE_UNITS = ["RV-110E", "HFUC-32-100", "indep-rv", "indep-hd"]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tcms_daq.sim.station_trials", description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--first-seed", type=int, default=1)
    parser.add_argument("--family", action="append", choices=sorted(FAMILIES))
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--coverage", action="store_true",
                        help="the four methods' U against the truth on stations with drawn instrument errors")
    parser.add_argument("--unit", action="append", choices=COVERAGE_UNITS,
                        help="with --coverage: only these units (default all, in this order)")
    parser.add_argument("--te-split", action="store_true",
                        help="the TE peak-to-peak's error on the coverage stations split by drawn instrument error")
    parser.add_argument("--te-encoder-lines", action="store_true",
                        help="the output encoder's order-1–2 error alone on the units' lines: its error and U")
    args = parser.parse_args(argv)
    if args.te_encoder_lines:
        for name in args.unit or ["RV-110E", "HFUC-32-100"]:
            row = te_encoder_on_lines(name, args.seeds, args.first_seed)
            print(f"{name} ({args.seeds} draws from seed {args.first_seed}): "
                  + "; ".join(f"{k} {v:.3g}" for k, v in row.items()), flush=True)
        return 0
    if args.te_split:
        split = {name: te_error_split(name, args.seeds, args.first_seed)
                 for name in (args.unit or ["RV-110E", "HFUC-32-100"])}
        if args.json:
            json.dump(split, sys.stdout, indent=2)
            print()
        else:
            for name, per_result in split.items():
                print(f"{name} ({args.seeds} stations from seed {args.first_seed})")
                for key, row in per_result.items():
                    print(f"  {key}: " + "; ".join(f"{k} {v:.3g}" for k, v in row.items()), flush=True)
        return 0
    if args.coverage:
        table = {}
        for name in args.unit or COVERAGE_UNITS:
            start = time.perf_counter()
            table[name] = coverage(name, args.seeds, args.first_seed)
            if not args.json:
                print(f"{name} ({args.seeds} stations, {time.perf_counter() - start:.0f} s)")
                for key, row in table[name].items():
                    print(f"  {key:40s} covered {row['covered']:6.1%}  median U {row['median_U']:.4g}  "
                          f"RMS error {row['rms_error']:.3g}  U/needed {row['U_over_needed']:.2f}", flush=True)
        if args.json:
            json.dump(table, sys.stdout, indent=2)
            print()
        return 0
    results = []
    for family in args.family or list(FAMILIES):
        start = time.perf_counter()
        r = rates(family, args.seeds, args.first_seed)
        r["seconds"] = round(time.perf_counter() - start, 1)
        results.append(r)
        if not args.json:
            keys = [k for k in ("named", "closed", "unexplained", "quiet", "amplitude_error_pct_max") if k in r]
            print(f"{family:18s} " + "  ".join(f"{k} {r[k]}" for k in keys) + f"  ({r['seconds']} s)", flush=True)
            for f in r["failures"]:
                print(f"    failed: {f}", flush=True)
    if args.json:
        json.dump(results, sys.stdout, indent=2, default=str)
        print()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

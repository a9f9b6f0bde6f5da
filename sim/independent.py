"""Trials on data the project did not generate: a reducer, a bench and effects written from physics here, not from the
simulated bench (``sim.physics``) nor from the catalogue's formulas (``tcms_daq.discrepancy.effects``).

The reducer is a two-slope spring (soft within ±T1 around zero torque: the lost-motion zone) with a Dahl friction
loop in torque; the programme is ±A triangle loops at two rates sampled at ``rate_hz``; the reducer follows the
continuous programme (its corners included); the torque reading has white noise, the angle reading an encoder's
noise and resolution. The "simulated" run is the same reducer, in one of two forms (``grid``):

* ``same_rows`` — driven by the torque *reading* (as a bench model is driven by the recorded trace), low-passed by a
  centred moving average over ``sim_torque_filter_s`` (20 ms: one sample at 50 Hz, 21 at 1 kHz) as a user drives a
  hysteresis model at kHz rates. Driven by the raw 1 kHz reading (``--raw-torque``) the Dahl loop follows the noise's
  reversals: its width falls to 53 % (200 N·m/s) and 69 % (600 N·m/s) of the true one — a real, rate-dependent
  difference between that simulation and the reducer, which the workflow rightly reports;
* ``own_grid`` — a model run on the programme on its own time grid (``SIM_RATE_FACTOR`` × the measured rate, its
  clock ``SIM_CLOCK_OFFSET_S`` apart), driven by the torque the family's physics gives the reading without its
  noise; the workflow's pairing puts it onto the measured rows.

Catalogue families, each by its physics: a transport delay of the torque channel, a temperature ramp through a
thermal coefficient, an encoder with a wrong line count, shaft torsion T/k between the measuring planes, bending
c·T², a sin/cos encoder with a gain imbalance read through atan2 (its error is at half the signal period), a
periodic gear-mesh error in the angle, backlash as a play operator on the angle, and a zero offset of the torque
reading (the simulation run on the offset reading).

Out-of-catalogue families: a dead zone on one side of zero torque, stick-slip at each reversal, a loop whose width
grows with the torque amplitude, a vibration periodic in time, lost counts (three permanent steps), and a stiffness
that drifts with a temperature ramp. Each carries where it is (time spans, a torque window with its direction, or a
period in time), so the trials check that the workflow's ``unexplained`` block locates it.

    python -m tcms_daq.sim.independent [--seeds 5] [--rate-hz 50 --rate-hz 1000] [--grid own_grid|both]
                                       [--family NAME] [--json | --markdown]

prints per family (grid and rate): extra names, parameters within 10 %, out-of-catalogue never ``explained`` and
located; ``--markdown`` the table of docs/discrepancy.md.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from tcms_daq.discrepancy import effects as fx
from tcms_daq.samples import Samples

K_NM_PER_ARCSEC = 5.0  # outer stiffness (300 N·m/arcmin)
K0_NM_PER_ARCSEC = 2.0  # inside the lost-motion zone
T1_NM = 40.0
DAHL_HALF_WIDTH_ARCSEC = 1.5
DAHL_TORQUE_NM = 60.0
SIM_RATE_FACTOR = 2.5  # own grid: the simulation's sample rate / the measured one
SIM_CLOCK_OFFSET_S = 2.345  # own grid: the simulation's clock reads this much more than the measurement's
GRIDS = ("same_rows", "own_grid")


@dataclass(frozen=True)
class Programme:
    amplitude_nm: float = 800.0
    rates_nm_per_s: tuple[float, ...] = (200.0, 600.0)
    loops_per_rate: int = 3
    rate_hz: float = 50.0
    torque_noise_nm: float = 0.3
    angle_noise_arcsec: float = 0.2
    resolution_arcsec: float = 0.05
    sim_torque_filter_s: float = 0.02  # same rows: the simulation's torque input, a centred moving average (0: raw)


def knots(p: Programme) -> tuple[np.ndarray, np.ndarray]:
    """(time s, torque N·m) of the programme's corners: from 0 to −A, then loops ±A at each rate, back to 0."""
    knots_t, knots_T, level, now = [0.0], [0.0], 0.0, 0.0
    for rate in p.rates_nm_per_s:
        for target in [-p.amplitude_nm] + [p.amplitude_nm, -p.amplitude_nm] * p.loops_per_rate:
            now += abs(target - level) / rate
            knots_t.append(now)
            knots_T.append(target)
            level = target
    now += abs(level) / p.rates_nm_per_s[0]
    knots_t.append(now)
    knots_T.append(0.0)
    return np.array(knots_t), np.array(knots_T)


def torque_path(p: Programme, t_s: np.ndarray) -> np.ndarray:
    """The applied torque at times ``t_s`` (piecewise linear between the :func:`knots`)."""
    return np.interp(t_s, *knots(p))


def duration_s(p: Programme) -> float:
    a, n = p.amplitude_nm, p.loops_per_rate
    return sum((a + 2 * a * 2 * n) / r for r in p.rates_nm_per_s) + a / p.rates_nm_per_s[0]


def spring_arcsec(torque_nm: np.ndarray) -> np.ndarray:
    """Two-slope spring: soft within ±T1, stiff outside (continuous)."""
    inner = np.clip(torque_nm, -T1_NM, T1_NM) / K0_NM_PER_ARCSEC
    return inner + (torque_nm - np.clip(torque_nm, -T1_NM, T1_NM)) / K_NM_PER_ARCSEC


def dahl_arcsec(torque_nm: np.ndarray, half_width_arcsec: float = DAHL_HALF_WIDTH_ARCSEC,
                torque_scale_nm: float = DAHL_TORQUE_NM) -> np.ndarray:
    """Dahl friction loop: dz/dT = (1 − z·sgn(dT))/T_s, exact per step; z ∈ (−1, 1), angle = w·z."""
    z = np.zeros(len(torque_nm))
    for i in range(1, len(torque_nm)):
        d = torque_nm[i] - torque_nm[i - 1]
        s = 1.0 if d >= 0 else -1.0
        z[i] = s + (z[i - 1] - s) * math.exp(-abs(d) / torque_scale_nm)
    return half_width_arcsec * z


def reducer_arcsec(torque_nm: np.ndarray) -> np.ndarray:
    return spring_arcsec(torque_nm) + dahl_arcsec(torque_nm)


def play(x: np.ndarray, width: float) -> np.ndarray:
    """Play (backlash) operator: the output stays until the input has moved half the width past it."""
    y = np.empty(len(x))
    y[0] = x[0] - width / 2
    for i in range(1, len(x)):
        y[i] = min(max(y[i - 1], x[i] - width / 2), x[i] + width / 2)
    return y


@dataclass
class Run:
    """One generated pair with its truth."""

    measured: Samples
    simulated: Samples
    truth: dict[str, float]  # catalogue name → primary parameter (catalogue families)
    where: dict[str, Any] = field(default_factory=dict)  # out-of-catalogue: where it is


@dataclass(frozen=True)
class Family:
    name: str
    description: str
    make: Maker
    in_catalogue: bool


def _grid(p: Programme) -> np.ndarray:
    return np.arange(0.0, duration_s(p), 1.0 / p.rate_hz)


TorqueFn = Callable[[np.ndarray, np.ndarray], np.ndarray]  # (time s, applied torque N·m) → torque N·m


def _applied(t: np.ndarray, applied: np.ndarray) -> np.ndarray:
    return applied


def reducer_on_programme(p: Programme, t_s: np.ndarray, torque_fn: TorqueFn = _applied) -> np.ndarray:
    """The reducer's angle at ``t_s`` (″) driven by ``torque_fn`` of the continuous programme: evaluated with the
    programme's corners inserted, so a corner between two samples is not cut off."""
    corners = knots(p)[0]
    dense = np.union1d(t_s, corners[(corners > t_s[0]) & (corners < t_s[-1])])
    angle = reducer_arcsec(torque_fn(dense, torque_path(p, dense)))
    return angle[np.searchsorted(dense, t_s)]


def moving_average(x: np.ndarray, samples: int) -> np.ndarray:
    """Centred moving average over ``samples`` (odd; the ends padded with the end values): zero phase, no lag."""
    if samples <= 1:
        return np.asarray(x, dtype=float)
    half = samples // 2
    c = np.concatenate(([0.0], np.cumsum(np.pad(np.asarray(x, dtype=float), half, mode="edge"))))
    return (c[samples:] - c[:-samples]) / samples


def _read(p: Programme, rng: np.random.Generator, t: np.ndarray, angle: np.ndarray, torque_fn: TorqueFn = _applied,
          grid: str = "same_rows") -> tuple[Samples, Samples]:
    """(measured, simulated): the readings of ``angle`` (″, at ``t``) and of the torque ``torque_fn`` gives the
    reading, and the reducer simulated on the same rows (driven by the filtered reading) or on its own grid."""
    reading = torque_fn(t, torque_path(p, t)) + rng.normal(0, p.torque_noise_nm, len(t))
    noisy = angle + rng.normal(0, p.angle_noise_arcsec, len(t))
    measured = Samples(t, reading, np.round(noisy / p.resolution_arcsec) * p.resolution_arcsec)
    if grid == "own_grid":
        ts = np.arange(0.0, duration_s(p), 1.0 / (SIM_RATE_FACTOR * p.rate_hz))
        simulated = Samples(ts + SIM_CLOCK_OFFSET_S, torque_fn(ts, torque_path(p, ts)),
                            reducer_on_programme(p, ts, torque_fn))
        return measured, simulated
    if grid != "same_rows":
        raise ValueError(f"grid must be one of {GRIDS}, got {grid!r}")
    window = int(round(p.sim_torque_filter_s * p.rate_hz)) | 1
    return measured, Samples(t, reading, reducer_arcsec(moving_average(reading, window)))


def _base(p: Programme) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    t = _grid(p)
    return t, torque_path(p, t), reducer_on_programme(p, t)


Maker = Callable[[Programme, np.random.Generator, str], "Run"]


def _catalogue(name: str, truth: float, angle_fn: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray],
               torque_fn: TorqueFn = _applied) -> Maker:
    def make(p: Programme, rng: np.random.Generator, grid: str) -> Run:
        t, applied, angle = _base(p)
        m, s = _read(p, rng, t, angle_fn(t, applied, angle), torque_fn, grid)
        return Run(m, s, {name: truth} if name else {})
    return make


def _delay(tau_s: float) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    return lambda t, applied: np.interp(t - tau_s, t, applied)


def _sincos_encoder(period_arcsec: float, gain_imbalance: float) -> Callable[[np.ndarray, np.ndarray, np.ndarray],
                                                                               np.ndarray]:
    """An interpolating encoder whose sine channel has gain 1 + g: the angle inside each signal period from atan2."""
    def read(t: np.ndarray, applied: np.ndarray, angle: np.ndarray) -> np.ndarray:
        phase = 2 * math.pi * angle / period_arcsec
        measured_phase = np.arctan2((1 + gain_imbalance) * np.sin(phase), np.cos(phase))
        wrapped = np.angle(np.exp(1j * (measured_phase - phase)))
        return angle + wrapped * period_arcsec / (2 * math.pi)
    return read


def _interp_amplitude(period_arcsec: float, g: float) -> float:
    """Amplitude of the half-period error of a gain imbalance g (first order: g/2 rad of phase)."""
    return abs(g / (2 + g)) * period_arcsec / (2 * math.pi)


# ---- out of the catalogue


def _one_sided_dead_zone(p: Programme, rng: np.random.Generator, grid: str) -> Run:
    t, applied, angle = _base(p)
    lo, hi = 100.0, 220.0  # loading only: the output stalls while the torque rises through [lo, hi] N·m, then
    rising = np.diff(applied, prepend=applied[0]) > 0  # catches up (a sticky spot on one flank of the teeth)
    inside = rising & (applied > lo) & (applied < hi)
    x = np.clip((applied - lo) / (hi - lo), 0.0, 1.0)
    lag = np.where(inside, np.minimum(x * (hi - lo) / K_NM_PER_ARCSEC, 3.0 * np.sin(math.pi * x)), 0.0)
    m, s = _read(p, rng, t, angle - lag, grid=grid)
    return Run(m, s, {}, {"torque_window_nm": (lo, hi), "direction": "loading"})


def _stick_slip(p: Programme, rng: np.random.Generator, grid: str) -> Run:
    t, applied, angle = _base(p)
    d = np.sign(np.diff(applied, prepend=applied[0]))
    rev = np.flatnonzero((d[1:] != d[:-1]) & (d[1:] != 0)) + 1
    extra = np.zeros(len(t))
    for i in rev:  # sticks for 0.4 s after each reversal (up to 2″ behind), then slips back
        k = (t >= t[i]) & (t < t[i] + 0.4)
        extra[k] -= 2.0 * d[i] * np.sin(math.pi * (t[k] - t[i]) / 0.4)
    m, s = _read(p, rng, t, angle + extra, grid=grid)
    return Run(m, s, {}, {"after_reversals": [float(t[i]) for i in rev]})


def _loop_grows(p: Programme, rng: np.random.Generator, grid: str) -> Run:
    t, applied, _ = _base(p)
    amplitude = np.maximum.accumulate(np.abs(applied))
    width = DAHL_HALF_WIDTH_ARCSEC * (1 + 1.0 * amplitude / p.amplitude_nm)  # double the width at full amplitude
    z = dahl_arcsec(applied, 1.0)
    angle = spring_arcsec(applied) + width * z
    m, s = _read(p, rng, t, angle, grid=grid)
    return Run(m, s, {}, {"loop_width": True})


def _vibration(p: Programme, rng: np.random.Generator, grid: str) -> Run:
    t, applied, angle = _base(p)
    period = 1.0 / 1.3
    m, s = _read(p, rng, t, angle + 0.4 * np.sin(2 * math.pi * t / period + rng.uniform(0, 6)), grid=grid)
    return Run(m, s, {}, {"period_s": period})


def _lost_counts(p: Programme, rng: np.random.Generator, grid: str) -> Run:
    t, applied, angle = _base(p)
    at = np.sort(rng.uniform(0.15, 0.85, 3)) * t[-1]
    steps = sum(1.2 * (t >= a) for a in at)
    m, s = _read(p, rng, t, angle + steps, grid=grid)
    return Run(m, s, {}, {"steps_at_s": [float(a) for a in at]})


def _stiffness_drift(p: Programme, rng: np.random.Generator, grid: str) -> Run:
    t, applied, _ = _base(p)
    factor = 1.0 - 0.03 * t / t[-1]  # the stiffness falls by 3 % over the test as the reducer warms
    angle = spring_arcsec(applied) / factor + dahl_arcsec(applied)
    m, s = _read(p, rng, t, angle, grid=grid)
    return Run(m, s, {}, {"time_span_s": (0.0, float(t[-1])), "grows_with_time": True})


FAMILIES: dict[str, Family] = {f.name: f for f in (
    Family("null", "the reducer as modelled", _catalogue("", 0.0, lambda t, a, th: th), True),
    Family("transport_delay", "the torque channel 20 ms late",
           _catalogue(fx.TIME_SKEW, 0.02, lambda t, a, th: th, _delay(0.02)), True),
    Family("temperature_ramp", "a frame warming 1.2 K/min at 1.5″/K",
           _catalogue(fx.THERMAL_DRIFT, 1.5 * 1.2 / 60, lambda t, a, th: th + 1.5 * 1.2 / 60 * t), True),
    Family("wrong_line_count", "an encoder with 0.8 % too many lines",
           _catalogue(fx.SCALE_ERROR, 0.008, lambda t, a, th: th * 1.008), True),
    Family("shaft_torsion", "a shaft of 400 N·m/″ between the measuring planes",
           _catalogue(fx.TORSION_OFFSET, 1 / 400, lambda t, a, th: th + a / 400), True),
    Family("bending", "bending of the measuring point, 2″ at 800 N·m, even in torque",
           _catalogue(fx.BENDING_DEFORMATION, 2 / 800 ** 2, lambda t, a, th: th + 2 * (a / 800) ** 2), True),
    Family("sincos_gain_imbalance", "a sin/cos encoder of 72″ signal period with a 6 % gain imbalance",
           _catalogue(fx.INTERPOLATION_ERROR, _interp_amplitude(72.0, 0.06), _sincos_encoder(72.0, 0.06)), True),
    Family("gear_mesh", "a 0.7″ error periodic in the angle at 95″",
           _catalogue(fx.PERIODIC_ERROR, 0.7, lambda t, a, th: th + 0.7 * np.sin(2 * math.pi * th / 95 + 0.4)), True),
    Family("play", "backlash: a 2.5″ play operator on the angle",
           _catalogue(fx.BACKLASH, 2.5, lambda t, a, th: play(th, 2.5)), True),
    Family("torque_reading_offset", "the torque reading 6 N·m high (the simulation run on the offset reading)",
           _catalogue(fx.TORQUE_ZERO_OFFSET, 6.0, lambda t, a, th: th, lambda t, a: a + 6.0), True),
    Family("one_sided_dead_zone", "a dead zone 100…220 N·m while loading only (stalls up to 3″, catches up)", _one_sided_dead_zone, False),
    Family("stick_slip", "stick-slip: up to 2″ behind for 0.4 s after each reversal", _stick_slip, False),
    Family("loop_grows_with_amplitude", "a friction loop twice as wide at full amplitude", _loop_grows, False),
    Family("vibration_in_time", "a 0.4″ vibration at 1.3 Hz", _vibration, False),
    Family("lost_counts", "three permanent 1.2″ steps (lost counts)", _lost_counts, False),
    Family("stiffness_drift", "the stiffness falls 3 % over the test as the reducer warms", _stiffness_drift, False),
)}


def located(family: str, where: dict[str, Any], unexplained: dict[str, Any] | None) -> bool:
    """Whether the ``unexplained`` block points at the hidden effect: its shape, period, time span or torque
    window and direction."""
    if not unexplained:
        return False
    shapes = [unexplained.get("shape_detail") or {}, *unexplained.get("shapes_considered", [])[:3]]
    best = unexplained.get("shape")
    if "period_s" in where:
        return any(s.get("shape") == "periodic_in_time" and abs(s["period_s"] / where["period_s"] - 1) < 0.05
                   for s in shapes)
    if "steps_at_s" in where:  # every step located within 1 s
        found = [x["at_time_s"] for s in unexplained.get("shapes_considered", []) if s.get("shape") == "step"
                 for x in s.get("steps", [])]
        return all(any(abs(f - a) < 1.0 for f in found) for a in where["steps_at_s"])
    if "torque_window_nm" in where:  # a window in the right direction overlapping the dead zone, not the whole range
        lo, hi = where["torque_window_nm"]
        return any(w["direction"] == where["direction"] and w["torque_range_nm"][0] < hi + 40
                   and w["torque_range_nm"][1] > lo - 40 and w["torque_range_nm"][1] - w["torque_range_nm"][0] < 600
                   for w in unexplained.get("torque_windows", []))
    if "after_reversals" in where:
        return bool(best and best.startswith("transition_after_reversal")) or best == "spikes"
    if where.get("loop_width"):
        return best in ("loop_width_change", "transition_after_reversal_in_torque")
    if where.get("grows_with_time"):
        return best == "stiffness_change_in_time"
    return False


@dataclass
class Outcome:
    family: str
    seed: int
    in_catalogue: bool
    verdict: str
    named: list[str]
    truth: dict[str, float]
    errors: dict[str, float]  # relative error of each hidden primary parameter that was named
    located: bool | None
    seconds: float
    grid: str = "same_rows"
    aliases: list[list[str]] = field(default_factory=list)  # alias groups reported (names), not named
    pairing: str = "same_rows"  # how the workflow put the simulation onto the measured rows
    rate_hz: float = 50.0

    @property
    def extra_names(self) -> list[str]:
        return sorted(set(self.named) - set(self.truth))

    def to_dict(self) -> dict[str, Any]:
        return {"family": self.family, "grid": self.grid, "rate_hz": self.rate_hz, "seed": self.seed,
                "in_catalogue": self.in_catalogue, "verdict": self.verdict,
                "named": self.named, "truth": self.truth, "errors": self.errors, "extra_names": self.extra_names,
                "aliases": self.aliases, "pairing": self.pairing, "located": self.located, "seconds": self.seconds}


def run_family(name: str, seed: int, programme: Programme = Programme(), grid: str = "same_rows") -> Outcome:
    from tcms_daq.discrepancy.workflow import run_discrepancy

    family = FAMILIES[name]
    run = family.make(programme, np.random.default_rng([seed, 2026]), grid)
    t0 = time.perf_counter()
    result = run_discrepancy(run.measured, run.simulated)
    seconds = time.perf_counter() - t0
    found = {e.name: e.parameters for e in result.effects}
    errors = {n: found[n][fx.REGISTRY[n].primary] / v - 1.0 for n, v in run.truth.items() if n in found}
    loc = None if family.in_catalogue else located(name, run.where, result.verdict.unexplained)
    return Outcome(name, seed, family.in_catalogue, result.verdict.verdict, result.names, run.truth, errors, loc,
                   seconds, grid, [list(a.names) for a in result.aliases],
                   result.pairing.mode if result.pairing is not None else "same_rows", programme.rate_hz)


def _label(o: Outcome, rates: int) -> str:
    grid = "" if o.grid == "same_rows" else f"@{o.grid}"
    return f"{o.family}{grid}" + (f"@{o.rate_hz:g}Hz" if rates > 1 else "")


def summarise(outcomes: list[Outcome]) -> dict[str, dict[str, Any]]:
    """Per family, grid (and rate, when there are several): runs, extra-name rate, named-right rate (hidden named,
    within 10 %), explained/located rates. Keys are ``family`` (same rows), ``family@own_grid`` (``…@1000Hz``)."""
    out: dict[str, dict[str, Any]] = {}
    rates = len({o.rate_hz for o in outcomes})
    for label in dict.fromkeys(_label(o, rates) for o in outcomes):
        runs = [o for o in outcomes if _label(o, rates) == label]
        row: dict[str, Any] = {"runs": len(runs), "extra_names": sum(bool(o.extra_names) for o in runs) / len(runs),
                               "verdicts": {v: sum(o.verdict == v for o in runs) for v in
                                            dict.fromkeys(o.verdict for o in runs)}}
        if runs[0].in_catalogue and runs[0].truth:
            row["named"] = sum(set(o.truth) <= set(o.named) for o in runs) / len(runs)
            row["within_10_percent"] = sum(bool(o.errors) and all(abs(e) <= 0.10 for e in o.errors.values())
                                           for o in runs) / len(runs)
            row["errors"] = [round(e, 4) for o in runs for e in o.errors.values()]
            if row["named"] < 1:  # what the runs that did not name it said instead
                row["not_named_aliases"] = sum(any(set(o.truth) & set(a) for a in o.aliases)
                                               for o in runs if not set(o.truth) <= set(o.named))
        if not runs[0].in_catalogue:
            row["explained"] = sum(o.verdict == "explained" for o in runs) / len(runs)
            row["located"] = sum(bool(o.located) for o in runs) / len(runs)
        out[label] = row
    return out


def markdown_table(outcomes: list[Outcome]) -> str:
    """A family per row, a (rate, grid) per column: for catalogue families the runs whose every named parameter is
    within 10 % with the largest |error|, extra names, verdicts other than the expected one; out of the catalogue,
    how many were ``explained`` and how many located."""
    columns = sorted({(o.rate_hz, o.grid) for o in outcomes}, key=lambda c: (c[0], GRIDS.index(c[1])))
    head = "| family | " + " | ".join(f"{r:g} Hz, {g.replace('_', ' ')}" for r, g in columns) + " |"
    lines = [head, "|---|" + "---|" * len(columns)]
    for family in dict.fromkeys(o.family for o in outcomes):
        cells = []
        for rate, grid in columns:
            runs = [o for o in outcomes if (o.family, o.rate_hz, o.grid) == (family, rate, grid)]
            if not runs:
                cells.append("")
                continue
            n, extra = len(runs), sum(bool(o.extra_names) for o in runs)
            other = [o.verdict for o in runs if o.truth and o.verdict != "explained"]
            if not runs[0].in_catalogue:
                cell = (f"explained {sum(o.verdict == 'explained' for o in runs)}/{n}, located "
                        f"{sum(bool(o.located) for o in runs)}/{n}")
            elif runs[0].truth:
                errors = [e for o in runs for e in o.errors.values()]
                within = sum(bool(o.errors) and set(o.truth) <= set(o.named)
                             and all(abs(e) <= 0.10 for e in o.errors.values()) for o in runs)
                cell = f"{within}/{n} within 10 %" + (f" (max {max(abs(e) for e in errors):.1%})" if errors else "")
            else:
                cell = f"{sum(o.verdict == 'consistent' for o in runs)}/{n} consistent"
            if runs[0].in_catalogue:
                cell += f", {extra} extra" if extra else ""
                if other:
                    cell += f", {len(other)} {other[0]}" if len(set(other)) == 1 else f", {len(other)} not explained"
            cells.append(cell)
        lines.append(f"| {family} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def totals(outcomes: list[Outcome]) -> dict[str, Any]:
    """The issue's criteria over all runs: extra names in catalogue runs (null included), named parameters within
    10 %, out-of-catalogue runs never ``explained`` and located."""
    cat_runs = [o for o in outcomes if o.in_catalogue]
    named = [e for o in cat_runs for e in o.errors.values()]
    out_runs = [o for o in outcomes if not o.in_catalogue]
    return {"catalogue_runs": len(cat_runs), "with_extra_names": sum(bool(o.extra_names) for o in cat_runs),
            "hidden_runs": sum(bool(o.truth) for o in cat_runs),
            "hidden_named": sum(bool(o.truth) and set(o.truth) <= set(o.named) for o in cat_runs),
            "named_parameters": len(named), "within_10_percent": sum(abs(e) <= 0.10 for e in named),
            "out_of_catalogue_runs": len(out_runs),
            "explained": sum(o.verdict == "explained" for o in out_runs),
            "located": sum(bool(o.located) for o in out_runs)}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tcms_daq.sim.independent", description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--first-seed", type=int, default=1)
    parser.add_argument("--family", action="append", choices=sorted(FAMILIES))
    parser.add_argument("--rate-hz", type=float, action="append", help="measured sample rate (repeat for several; "
                        "default 50)")
    parser.add_argument("--grid", choices=[*GRIDS, "both"], default="same_rows",
                        help="the simulation on the measured rows, on its own time grid, or both")
    parser.add_argument("--raw-torque", action="store_true",
                        help="same rows: drive the simulation by the raw torque reading (no 20 ms moving average)")
    parser.add_argument("--torque-noise-nm", type=float, default=Programme.torque_noise_nm,
                        help="white noise of the torque reading (N·m, default %(default)s)")
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--markdown", action="store_true", help="print the per-family table only")
    args = parser.parse_args(argv)
    grids = GRIDS if args.grid == "both" else (args.grid,)
    rates = args.rate_hz or [50.0]
    outcomes = []
    for rate in rates:
        programme = Programme(rate_hz=rate, sim_torque_filter_s=0.0 if args.raw_torque else 0.02,
                              torque_noise_nm=args.torque_noise_nm)
        for name in args.family or FAMILIES:
            for grid in grids:
                for seed in range(args.first_seed, args.first_seed + args.seeds):
                    o = run_family(name, seed, programme, grid)
                    outcomes.append(o)
                    if not (args.json or args.markdown):
                        print(f"{_label(o, len(rates)):45s} seed {seed}: {o.verdict:20s} named {o.named or '-'} "
                              f"{' '.join(f'{k} {v:+.1%}' for k, v in o.errors.items())}"
                              f"{' aliases ' + str(o.aliases) if o.aliases else ''}"
                              f"{'' if o.located is None else ' located' if o.located else ' NOT located'} "
                              f"({o.seconds:.1f} s)", flush=True)
    summary = summarise(outcomes)
    total = totals(outcomes)
    if args.markdown:
        print(markdown_table(outcomes), end="")
    elif args.json:
        print(json.dumps({"summary": summary, "totals": total, "runs": [o.to_dict() for o in outcomes]}, indent=1))
    else:
        for name, row in summary.items():
            print(f"{name:45s} " + ", ".join(f"{k} {v:.0%}" if isinstance(v, float) else f"{k} {v}"
                                             for k, v in row.items()))
        t = total
        print(f"extra names in {t['with_extra_names']} of {t['catalogue_runs']} catalogue runs; hidden effect named "
              f"in {t['hidden_named']} of {t['hidden_runs']}, {t['within_10_percent']} of {t['named_parameters']} "
              f"named parameters within 10 %; out of the catalogue: explained {t['explained']} of "
              f"{t['out_of_catalogue_runs']}, located {t['located']} of {t['out_of_catalogue_runs']}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

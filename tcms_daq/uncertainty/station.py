"""GUM budgets (JCGM 100) of the turning tests: transmission error, starting torque, no-load torque, efficiency.

The arithmetic is the stiffness test's (``tcms_daq.uncertainty.budget.combine``: GTC, Welch–Satterthwaite, t-based
k for 95 %), the lines as there: Type A from the record (the scatter of ramps or whole-revolution blocks; for the
transmission error the noise around each line of the spectrum), Type B from the declared chain
(``[uncertainty.station]``, ``StationUncertainty``) with sensitivities through the evaluation itself where the error
enters the record in a known way (a torque scale or zero, the skew between the two angle readings: the record is
perturbed by ± the step and evaluated again; central differences for the torques, the skew's into the transmission
error's Monte Carlo below).

Transmission error (per direction's peak-to-peak, the larger of the two, and each order's amplitude). The noise,
the encoders' errors and the skew move the fitted lines' coefficients linearly, but an amplitude or a peak-to-peak is not
linear in them (a small line's amplitude grows with any error across it): their lines are a Monte Carlo over the
coefficients (JCGM 101 on the fitted model, 400 draws whose sample covariance is made exactly the declared one, so
that the part linear in them is exact and only the non-linear part is sampled): the RMS change of each result, its
spread and its mean shift together.

* noise — each line's coefficients with the noise around it (√(E|A|²/2) from ~130 bins; Type A, 100 dof);
* output encoder (orders 1–2) — its error over the revolution (``output_encoder_u_arcsec``, RMS: mounting and
  graduation; shared by the two orders, each a cosine and a sine of standard uncertainty u/√2), the same in both
  directions, through the fit of each shape with the record's columns;
* input encoder (once per input turn) — its error (``input_encoder_u_arcsec``, RMS, input arcsec: a cosine and a
  sine of that standard uncertainty of the input angle), read as −e/i on the TE;
* output encoder (higher orders) — ``output_encoder_high_order_u_arcsec`` (RMS) as a sinusoid of unknown phase at a
  line's order (sensitivity 1), on the peak-to-peak √2 (at the maximum and the minimum);
* lines below the detection threshold — a line of at most the threshold amplitude A_th may have been left out; it
  moves the peak-to-peak by at most 2·A_th (rectangular);
* synchronisation — the input angle latched ±``sync_skew_u_s`` later, evaluated again with the same orders (it
  carries the measured speed and its ripple; a constant skew at a constant speed only shifts the TE): the change
  of each direction's coefficients per unit skew, one skew drawn for both directions in the Monte Carlo (it moves
  them in opposite senses, so the larger direction's peak-to-peak rises for a skew of either sign: a central
  difference through that maximum gave almost nothing);
* speed ripple — the record resampled onto the angle grid linearly instead of by a cubic spline, evaluated again:
  half the difference, rectangular (the samples are uneven in angle by the speed ripple).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
from GTC import type_a
from threadpoolctl import threadpool_limits

from tcms_daq.analysis.noise import white_noise_std
from tcms_daq.config.models import StationUncertainty, TorqueUncertainty
from tcms_daq.errors import EvaluationError
from tcms_daq.transmission.kinematics import Teeth
from tcms_daq.transmission.te import (
    FALSE_ALARM,
    TeDirection,
    TeEvaluation,
    TeLine,
    TeRecord,
    evaluate_transmission_error,
    te_records,
)
from tcms_daq.transmission.torque import (
    EfficiencyEvaluation,
    NoLoadTorqueEvaluation,
    StartingTorqueEvaluation,
    evaluate_efficiency,
    evaluate_no_load_torque,
    evaluate_starting_torque,
)
from tcms_daq.uncertainty.budget import Budget, Contribution, combine
from tcms_daq.units import ARCSEC_PER_RAD

NOISE_DOF = 100.0  # the noise level of a line comes from ~130 bins around it
MC_DRAWS = 400
NOISE_SEED = 20_261_127
BOOTSTRAP_DRAWS = 8

Arrays = dict[str, np.ndarray]


def te_order_name(line: TeLine) -> str:
    """The result name of a line's amplitude: ``te_order_39_amplitude_arcsec``."""
    return f"te_order_{line.order_per_output_rev:.4g}_amplitude_arcsec"


def _te_values(ev: TeEvaluation) -> dict[str, float]:
    out = {"transmission_error_arcsec": ev.transmission_error_arcsec}
    out.update({f"{d}_transmission_error_arcsec": v.peak_to_peak_arcsec for d, v in ev.per_direction.items()})
    out.update({te_order_name(line): line.amplitude_arcsec for line in ev.te_orders})
    return out


def _match(values: dict[str, float], moved: TeEvaluation) -> dict[str, float]:
    """``moved``'s values under the nominal names (orders matched to the nearest line)."""
    out = {k: v for k, v in _te_values(moved).items() if not k.startswith("te_order_")}
    for name in values:
        if name.startswith("te_order_"):
            k = float(name.split("_")[2])
            near = min(moved.te_orders, key=lambda ln: abs(ln.order_per_output_rev - k), default=None)
            if near is not None and abs(near.order_per_output_rev - k) < 0.5:
                out[name] = near.amplitude_arcsec
    return out


@dataclass(frozen=True)
class _Lines:
    """One direction's lines as coefficients of TE = Σ c·cos kφ + s·sin kφ, and the dense grid of its span."""

    orders: np.ndarray
    coef: np.ndarray  # [c1, s1, c2, s2, …]
    u: np.ndarray  # each line's noise u, per coefficient
    cos: np.ndarray
    sin: np.ndarray
    phi: np.ndarray  # the record's even grid (rad)
    direction: TeDirection


def _lines_of(d: TeDirection) -> _Lines:
    k = np.array([ln.order_per_output_rev for ln in d.lines])
    coef = np.array([x for ln in d.lines for x in (ln.amplitude_arcsec * math.sin(math.radians(ln.phase_deg)),
                                                   ln.amplitude_arcsec * math.cos(math.radians(ln.phase_deg)))])
    top = float(k.max()) if k.size else 1.0
    dense = np.linspace(d.phi_start_rad, d.phi_end_rad, max(2048, int(16 * top * d.revolutions)))
    grid = d.phi_start_rad + np.arange(d.samples) * (d.phi_end_rad - d.phi_start_rad) / d.samples
    u = np.repeat([ln.u_amplitude_arcsec for ln in d.lines], 2)
    return _Lines(k, coef, u, np.cos(np.outer(k, dense)), np.sin(np.outer(k, dense)), grid, d)


def _shape_response(lines: _Lines, shapes: np.ndarray) -> np.ndarray:
    """How each line's coefficients move when the record moves by each shape (columns of ``shapes`` on the
    record's grid): the least-squares fit of the shape with the record's columns (the constant, the trend, the
    lines), rows = shapes."""
    phi = lines.phi
    cols = [np.ones_like(phi), phi - phi.mean()]
    for k in lines.orders:
        cols += [np.cos(k * phi), np.sin(k * phi)]
    coef, *_ = np.linalg.lstsq(np.column_stack(cols), shapes, rcond=None)
    return np.asarray(coef[2:].T)


def _results_of(ev: TeEvaluation, per: dict[str, _Lines], coefs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The TE results for draws of every direction's coefficients (arrays draws × 2L): each direction's peak-to-peak,
    the larger, and each combined line's amplitude (the mean of the directions' phasors at its order)."""
    out: dict[str, np.ndarray] = {}
    for name, lines in per.items():
        c, s = coefs[name][:, 0::2], coefs[name][:, 1::2]
        te = c @ lines.cos + s @ lines.sin
        out[f"{name}_transmission_error_arcsec"] = te.max(axis=1) - te.min(axis=1)
    out["transmission_error_arcsec"] = np.maximum.reduce([out[f"{n}_transmission_error_arcsec"] for n in per])
    tolerance = 0.5 / min(d.revolutions for d in ev.per_direction.values())
    for line in ev.te_orders:
        phasors = []
        for name, lines in per.items():
            idx = np.flatnonzero(np.abs(lines.orders - line.order_per_output_rev) <= tolerance)
            if idx.size:
                j = int(idx[np.argmin(np.abs(lines.orders[idx] - line.order_per_output_rev))])
                phasors.append(coefs[name][:, 2 * j + 1] + 1j * coefs[name][:, 2 * j])
        if phasors:
            out[te_order_name(line)] = np.abs(np.mean(phasors, axis=0))
    return out


def standard_normal_draws(rng: np.random.Generator, draws: int, dims: int) -> np.ndarray:
    """``draws`` × ``dims`` draws of N(0, 1) moved so that their sample mean is 0 and their sample covariance is
    exactly the identity (centred, then whitened by the Cholesky factor of their covariance): a result linear in
    them gets its variance exactly, and only its non-linear part is left to the sampling. Fewer than 2·dims draws
    are centred only (their covariance is too poorly conditioned to whiten)."""
    x = rng.standard_normal((draws, dims))
    x -= x.mean(axis=0)
    if draws < 2 * dims:
        return x
    factor = np.linalg.cholesky(x.T @ x / draws)
    return np.linalg.solve(factor, x.T).T


def _line_monte_carlo(ev: TeEvaluation, per: dict[str, _Lines], sources: dict[str, np.ndarray],
                      sigma: float, draws: int, shared: bool, rng: np.random.Generator) -> dict[str, float]:
    """RMS change of each result (its spread and its mean shift: an amplitude or a peak-to-peak is not linear in the
    coefficients, and a small line's amplitude grows with any error across it) when the coefficients move by
    ``sources[direction]`` (shapes × 2L) times draws of N(0, σ²) per shape, the same draw in both directions when
    ``shared`` (one encoder's error), else independent. The draws' sample covariance is exactly σ²·I
    (``standard_normal_draws``): with a few hundred plain draws the same set for every record (a fixed seed) is
    a few per cent off in RMS, and every record's line with it."""
    nominal = {k: v[0] for k, v in _results_of(ev, per, {n: ln.coef[None, :] for n, ln in per.items()}).items()}
    common = sigma * standard_normal_draws(rng, draws, next(iter(sources.values())).shape[0])
    coefs = {}
    for name, lines in per.items():
        x = common if shared else sigma * standard_normal_draws(rng, draws, sources[name].shape[0])
        coefs[name] = lines.coef[None, :] + x @ sources[name]
    moved = _results_of(ev, per, coefs)
    return {k: float(np.sqrt(np.mean((v - nominal[k]) ** 2))) for k, v in moved.items() if k in nominal}


def te_budgets(time_s: npt.ArrayLike, input_angle_arcsec: npt.ArrayLike, output_angle_arcsec: npt.ArrayLike,
               nominal: TeEvaluation, chain: StationUncertainty | None = None, *, teeth: Teeth | None = None,
               max_order_per_output_rev: float | None = None) -> dict[str, Budget]:
    """The budget of every result of the transmission-error evaluation ``nominal`` of these arrays (module
    docstring); ``chain`` None: the record's own (Type A) lines only."""
    t = np.asarray(time_s, dtype=float)
    a_in = np.asarray(input_angle_arcsec, dtype=float)
    a_out = np.asarray(output_angle_arcsec, dtype=float)
    values = _te_values(nominal)
    chain = chain or StationUncertainty()
    known = {d: [ln.order_per_output_rev for ln in v.lines] for d, v in nominal.per_direction.items()}

    def again(angle_in: np.ndarray, angle_out: np.ndarray = a_out, resample: str = "cubic") -> dict[str, float]:
        return _match(values, _moved(t, angle_in, angle_out, nominal, teeth, max_order_per_output_rev, known,
                                     resample))

    lines: dict[str, list[Contribution]] = {name: [] for name in values}
    u_skew = chain.sync_skew_u_s
    # the skew: each direction's lines re-fitted with the input latched ±u later (it carries the measured speed and
    # its ripple); the change of their coefficients per unit skew goes into the Monte Carlo below, one skew shared
    # by both directions (it moves them in opposite senses: the larger direction's peak-to-peak is not linear in it)
    skewed = ([_moved(t, np.interp(t - x, t, a_in), a_out, nominal, teeth, max_order_per_output_rev, known)
               for x in (u_skew, -u_skew)] if u_skew > 0 else [])
    linear = again(a_in, a_out, "linear")
    for name in values:
        if name in linear:
            half = abs(linear[name] - values[name]) / 2.0
            if half > 0:
                lines[name].append(Contribution("speed ripple (resampling onto the angle grid)", "arcsec",
                                                half / math.sqrt(3.0), 1.0))
    # the encoders' errors and the noise: Monte Carlo over the lines' coefficients (each source moves them linearly,
    # the results are not linear in them: JCGM 101 on the fitted model)
    rng = np.random.default_rng(NOISE_SEED)
    per = {name: _lines_of(d) for name, d in nominal.per_direction.items() if d.lines}
    with threadpool_limits(limits=1, user_api="blas"):
        mc: dict[str, dict[str, float]] = {}
        if per:
            noise = {name: np.diag(ln.u) for name, ln in per.items()}
            mc["noise"] = _line_monte_carlo(nominal, per, noise, 1.0, MC_DRAWS, False, rng)
            if chain.output_encoder_u_arcsec > 0:
                shapes = {name: _shape_response(ln, np.column_stack(
                    [f(m * ln.phi) for m in (1, 2) for f in (np.cos, np.sin)])) for name, ln in per.items()}
                mc["output encoder (orders 1–2)"] = _line_monte_carlo(
                    nominal, per, shapes, chain.output_encoder_u_arcsec / math.sqrt(2.0), MC_DRAWS, True, rng)
            if chain.input_encoder_u_arcsec > 0:
                i = nominal.ratio
                shapes = {}
                for name, ln in per.items():
                    theta_in = i * (ln.phi - ln.direction.offset_arcsec / ARCSEC_PER_RAD)
                    # the input's error e reads as −e/i on the TE (θ_out − θ_in/i)
                    shapes[name] = -_shape_response(ln, np.column_stack([np.cos(theta_in), np.sin(theta_in)])) / i
                mc["input encoder (once per input turn)"] = _line_monte_carlo(
                    nominal, per, shapes, chain.input_encoder_u_arcsec, MC_DRAWS, True, rng)
            if skewed:
                shapes = {name: ((_coefficients_at(skewed[0].per_direction[name], ln.orders)
                                  - _coefficients_at(skewed[1].per_direction[name], ln.orders)) / (2.0 * u_skew))[None, :]
                          for name, ln in per.items()}
                skew = _line_monte_carlo(nominal, per, shapes, u_skew, MC_DRAWS, True, rng)
                for name, u in skew.items():
                    if name in lines and u > 0:
                        lines[name].append(Contribution(SKEW_SOURCE, "s", u_skew, u / u_skew))
    for source, changes in mc.items():
        if source == "noise":
            continue
        for name, u in changes.items():
            if name in lines and u > 0:
                lines[name].append(Contribution(source, "arcsec", u, 1.0))
    threshold = max(_threshold_amplitude(d) for d in nominal.per_direction.values())
    u_high = chain.output_encoder_high_order_u_arcsec
    type_a_u: dict[str, float] = {}
    for name in values:
        if name.startswith("te_order_"):
            line = next(ln for ln in nominal.te_orders if te_order_name(ln) == name)
            if line.order_per_output_rev > 2.5:  # the encoder's higher orders: a sinusoid of unknown phase there
                lines[name].append(Contribution("output encoder (higher orders)", "arcsec", u_high, 1.0))
        else:
            lines[name].append(Contribution("output encoder (higher orders)", "arcsec", u_high, math.sqrt(2.0)))
            lines[name].append(Contribution("lines below the detection threshold", "arcsec",
                                            threshold / math.sqrt(3.0), 2.0))
        type_a_u[name] = mc.get("noise", {}).get(name, 0.0)
    return {name: combine(values[name], "arcsec", type_a_u[name], NOISE_DOF, _type_a_source(name),
                          [c for c in lines[name] if c.u > 0]) for name in values}


SKEW_SOURCE = "synchronisation (skew of the angle readings)"


def _moved(t: np.ndarray, angle_in: np.ndarray, angle_out: np.ndarray, nominal: TeEvaluation, teeth: Teeth | None,
           max_order_per_output_rev: float | None, known: dict[str, list[float]], resample: str = "cubic"
           ) -> TeEvaluation:
    """The record evaluated again with the nominal evaluation's orders (no detection)."""
    return evaluate_transmission_error(t, angle_in, angle_out, ratio=nominal.ratio, teeth=teeth,
                                       max_order_per_output_rev=max_order_per_output_rev, known_orders=known,
                                       detect=False, resample=resample)


def _coefficients_at(d: TeDirection, orders: np.ndarray) -> np.ndarray:
    """[c1, s1, c2, s2 …] (TE = Σ c·cos kφ + s·sin kφ) of a direction's lines nearest to each of ``orders``."""
    out = []
    for k in orders:
        line = min(d.lines, key=lambda ln: abs(ln.order_per_output_rev - k))
        phase = math.radians(line.phase_deg)
        out += [line.amplitude_arcsec * math.sin(phase), line.amplitude_arcsec * math.cos(phase)]
    return np.array(out)


def _type_a_source(name: str) -> str:
    return f"noise around the lines ({MC_DRAWS} draws of their coefficients)"


def _threshold_amplitude(d: TeDirection) -> float:
    """The smallest amplitude the pursuit takes as a line in this direction (the noise level × its threshold)."""
    bins = max(2, int(d.samples / 4.0))
    return math.sqrt(math.log(bins / FALSE_ALARM)) * d.noise_amplitude_arcsec


def te_allowance(time_s: npt.ArrayLike, input_angle_arcsec: npt.ArrayLike, output_angle_arcsec: npt.ArrayLike, *,
                 ratio: float, chain: StationUncertainty | None) -> Callable[[list[float]], list[float]]:
    """What the measuring chain alone can make at each of a list of orders (″, expanded, k = 2): the output
    encoder (√2·u at orders ≤ 2, the high-order u above), the input encoder (√2·u/i at the input's order and its
    2×), and the skew of the readings (the record evaluated with the input latched ±u later, the change of each
    order's complex amplitude; the larger direction's). For ``te_model.compare_te``."""
    t = np.asarray(time_s, dtype=float)
    a_in = np.asarray(input_angle_arcsec, dtype=float)
    a_out = np.asarray(output_angle_arcsec, dtype=float)
    chain = chain or StationUncertainty()

    def allowance(orders: list[float]) -> list[float]:
        with threadpool_limits(limits=1, user_api="blas"):
            return _allowance(orders)

    def _allowance(orders: list[float]) -> list[float]:
        records = te_records(t, a_in, a_out, ratio=ratio)
        revolutions = min(r.revolutions for r in records.values())
        skew = np.zeros(len(orders))
        if chain.sync_skew_u_s > 0 and orders:
            u = chain.sync_skew_u_s
            moved = [te_records(t, np.interp(t - x, t, a_in), a_out, ratio=ratio) for x in (u, -u)]
            for name in records:
                plus = _phasors(moved[0][name], orders)
                minus = _phasors(moved[1][name], orders)
                skew = np.maximum(skew, np.abs(plus - minus) / 2.0)
        out = []
        for idx, k in enumerate(orders):
            # a finding is a vector: what the chain can add there is a sinusoid of any phase, whose amplitude has
            # the RMS √2·u
            u_enc = chain.output_encoder_u_arcsec if k <= 2.5 else chain.output_encoder_high_order_u_arcsec
            parts = [math.sqrt(2.0) * u_enc, skew[idx]]
            if any(abs(k - m * ratio) <= 0.5 / revolutions for m in (1, 2)):
                parts.append(math.sqrt(2.0) * chain.input_encoder_u_arcsec / ratio)
            out.append(2.0 * math.sqrt(sum(p * p for p in parts)))
        return out

    return allowance


def _phasors(record: TeRecord, orders: list[float]) -> np.ndarray:
    """The complex amplitudes (s + i·c: TE = A·sin(kφ + ϕ)) of a record at fixed orders, fitted jointly."""
    a = np.column_stack([np.ones_like(record.phi_rad), record.phi_rad - record.phi_rad.mean()]
                        + [f(k * record.phi_rad) for k in orders for f in (np.cos, np.sin)])
    coef, *_ = np.linalg.lstsq(a, record.te_arcsec, rcond=None)
    return np.array([complex(coef[3 + 2 * i], coef[2 + 2 * i]) for i in range(len(orders))])


# ------------------------------------------------------------------------------------------------- torque methods


@dataclass(frozen=True)
class _Input:
    name: str
    unit: str
    u: float
    step: float
    apply: Callable[[Arrays, float], Arrays]


def _torque_inputs(channel: str, declared: TorqueUncertainty, scale_step: float = 1e-3, zero_step: float = 1e-4
                   ) -> list[_Input]:
    """The scale and zero of one torque channel (``input_torque_nm`` or ``output_torque_nm``) as record
    perturbations."""
    label = channel.removesuffix("_nm").replace("_", " ")

    def scale(arrays: Arrays, x: float) -> Arrays:
        return {**arrays, channel: arrays[channel] * (1.0 + x)}

    def zero(arrays: Arrays, x: float) -> Arrays:
        return {**arrays, channel: arrays[channel] + x}

    out = []
    if declared.u_rel > 0:
        out.append(_Input(f"{label} scale", "1", declared.u_rel, max(declared.u_rel, scale_step), scale))
    if declared.u_zero_nm > 0:
        out.append(_Input(f"{label} zero", "N·m", declared.u_zero_nm, max(declared.u_zero_nm, zero_step), zero))
    return out


def _through(arrays: Arrays, evaluate: Callable[[Arrays], dict[str, float]], inputs: list[_Input],
             names: list[str]) -> dict[str, list[Contribution]]:
    out: dict[str, list[Contribution]] = {name: [] for name in names}
    for inp in inputs:
        try:
            plus, minus = evaluate(inp.apply(arrays, inp.step)), evaluate(inp.apply(arrays, -inp.step))
        except EvaluationError as exc:
            raise EvaluationError(f"uncertainty budget: the evaluation fails with {inp.name} moved by "
                                  f"±{inp.step:.3g} {inp.unit}: {exc}") from None
        for name in names:
            if name in plus and name in minus:
                out[name].append(Contribution(inp.name, inp.unit, inp.u, (plus[name] - minus[name]) / (2 * inp.step)))
    return out


def _blocks_type_a(blocks: list[float]) -> tuple[float | None, float | None]:
    if len(blocks) < 2:
        return None, None
    est = type_a.estimate(blocks)
    return float(est.u), float(est.df)


def _bootstrap(arrays: Arrays, evaluate: Callable[[Arrays], dict[str, float]], channels: list[str],
               names: list[str]) -> dict[str, tuple[float, float]]:
    """(u, dof) of each result from re-evaluations with fresh white noise of the measured size on ``channels``."""
    rng = np.random.default_rng(NOISE_SEED)
    sigma = {c: white_noise_std(arrays[c]) for c in channels}
    draws: dict[str, list[float]] = {n: [] for n in names}
    for _ in range(BOOTSTRAP_DRAWS):
        moved = {**arrays, **{c: arrays[c] + sigma[c] * rng.standard_normal(arrays[c].size) for c in channels}}
        try:
            values = evaluate(moved)
        except EvaluationError:
            continue
        for n in names:
            if n in values:
                draws[n].append(values[n])
    return {n: (float(np.std(v, ddof=1)), len(v) - 1.0) for n, v in draws.items() if len(v) >= 2}


def _combine_all(values: dict[str, float], unit: str, blocks: Callable[[str], list[float]],
                 contributions: dict[str, list[Contribution]], block_word: str,
                 fallback: dict[str, tuple[float, float]] | None = None) -> dict[str, Budget]:
    out = {}
    for name, value in values.items():
        u, dof = _blocks_type_a(blocks(name))
        source = f"repeatability ({block_word}, n = {len(blocks(name))})"
        if u is None and fallback and name in fallback:
            (u, dof), source = fallback[name], f"noise within the record ({BOOTSTRAP_DRAWS} re-evaluations)"
        out[name] = combine(value, unit, u, dof, source, [c for c in contributions.get(name, []) if c.u > 0])
    return out


def starting_torque_budgets(time_s: npt.ArrayLike, input_torque_nm: npt.ArrayLike, input_angle_arcsec: npt.ArrayLike,
                            nominal: StartingTorqueEvaluation, chain: StationUncertainty | None = None
                            ) -> dict[str, Budget]:
    """Budgets of the starting torque (per direction and the larger): the ramps' scatter (one ramp: the record's
    noise, re-evaluated), the input torque's scale and zero, the onset's location between samples (the torque's
    rise over one sample period, rectangular)."""
    chain = chain or StationUncertainty()
    arrays = {"time_s": np.asarray(time_s, float), "input_torque_nm": np.asarray(input_torque_nm, float),
              "input_angle_arcsec": np.asarray(input_angle_arcsec, float)}

    def evaluate(a: Arrays) -> dict[str, float]:
        return evaluate_starting_torque(a["time_s"], a["input_torque_nm"], a["input_angle_arcsec"]).values()

    values = nominal.values()
    contributions = _through(arrays, evaluate, _torque_inputs("input_torque_nm", chain.input_torque), list(values))
    for name in values:  # the onset is located between samples by the fit: at most a sample's torque rise off
        direction = name.split("_")[0] if name.split("_")[0] in ("forward", "reverse") else max(
            nominal.per_direction, key=lambda d: nominal.per_direction[d])
        rise = [r.rate_nm_per_s * r.sample_period_s for r in nominal.ramps if r.direction == direction]
        if rise:
            contributions[name].append(Contribution("onset between samples (ramp rate × sample period)", "N·m",
                                                    float(np.mean(rise)) / math.sqrt(3.0), 1.0))
    single = [n for n in values if len(nominal.blocks(n)) < 2]
    fallback = _bootstrap(arrays, evaluate, ["input_torque_nm", "input_angle_arcsec"], single) if single else None
    return _combine_all(values, "N·m", nominal.blocks, contributions, "ramps", fallback)


def no_load_torque_budgets(time_s: npt.ArrayLike, input_torque_nm: npt.ArrayLike, input_angle_arcsec: npt.ArrayLike,
                           nominal: NoLoadTorqueEvaluation, chain: StationUncertainty | None = None
                           ) -> dict[str, Budget]:
    """Budgets of the no-load torque at each speed (and per direction): the blocks' scatter, the input torque's
    scale and zero (the zero cancels in the two directions' half-difference: its sensitivity comes out 0)."""
    chain = chain or StationUncertainty()
    arrays = {"time_s": np.asarray(time_s, float), "input_torque_nm": np.asarray(input_torque_nm, float),
              "input_angle_arcsec": np.asarray(input_angle_arcsec, float)}
    speeds = list(nominal.per_speed)

    def evaluate(a: Arrays) -> dict[str, float]:
        return evaluate_no_load_torque(a["time_s"], a["input_torque_nm"], a["input_angle_arcsec"],
                                       speeds_rpm=speeds).values()

    values = nominal.values()
    contributions = _through(arrays, evaluate, _torque_inputs("input_torque_nm", chain.input_torque), list(values))
    return _combine_all(values, "N·m", nominal.blocks, contributions, "blocks of whole input revolutions")


def efficiency_budgets(time_s: npt.ArrayLike, input_torque_nm: npt.ArrayLike, input_angle_arcsec: npt.ArrayLike,
                       output_torque_nm: npt.ArrayLike, output_angle_arcsec: npt.ArrayLike,
                       nominal: EfficiencyEvaluation, chain: StationUncertainty | None = None) -> dict[str, Budget]:
    """Budgets of the efficiency per direction: the blocks' scatter, both torque channels' scale and zero."""
    chain = chain or StationUncertainty()
    arrays = {"time_s": np.asarray(time_s, float), "input_torque_nm": np.asarray(input_torque_nm, float),
              "input_angle_arcsec": np.asarray(input_angle_arcsec, float),
              "output_torque_nm": np.asarray(output_torque_nm, float),
              "output_angle_arcsec": np.asarray(output_angle_arcsec, float)}

    def evaluate(a: Arrays) -> dict[str, float]:
        return evaluate_efficiency(a["time_s"], a["input_torque_nm"], a["input_angle_arcsec"], a["output_torque_nm"],
                                   a["output_angle_arcsec"]).values()

    values = nominal.values()
    inputs = (_torque_inputs("input_torque_nm", chain.input_torque)
              + _torque_inputs("output_torque_nm", chain.output_torque, zero_step=1e-2))
    contributions = _through(arrays, evaluate, inputs, list(values))
    return _combine_all(values, "1", nominal.blocks, contributions, "blocks of the steady stretch")


def attach(evaluation: Any, budgets: dict[str, Budget]) -> Any:
    """Store the budgets on an evaluation in their JSON form (``evaluation.uncertainty``)."""
    evaluation.uncertainty = {name: b.to_dict() for name, b in budgets.items()}
    return evaluation

"""Transmission error (GB/T 35089 §8): TE = output angle − input angle / i, per direction, over whole output
revolutions; its peak-to-peak, its curve against the output angle, and its orders with the components they name.

Per direction of rotation (the longest stretch at the direction's running speed):

1. φ = θ_in/i, moved onto the output encoder's zero (φ + the median of θ_out − θ_in/i): the output angle the input
   says, so the TE curve and the phases refer to the output encoder's angle; TE = θ_out − φ.
2. The largest whole number N of output revolutions in the stretch; TE resampled onto a uniform grid of φ (cubic
   spline: the samples are uniform in time, not in angle, when the speed ripples).
3. The spectrum over N revolutions has bins every 1/N order. Lines are found one at a time, strongest first (a
   matching pursuit): the bin standing out of the local noise level (the median of the squared amplitudes around
   it, which is the noise's E|A|²·ln 2) by more than a threshold that keeps the chance of a noise line in the band
   below ``false_alarm``; its order refined by least squares (an order need not sit on a bin: RV input orders such
   as 175.28), then all lines and a straight line a + b·φ are fitted jointly and the next line is sought in the
   residual. b is a scale mismatch of the two encoders (a periodic TE has no trend over whole revolutions): it is
   reported, not counted as TE.
4. The TE curve is the sum of the lines (noise and the trend left out): its peak-to-peak is the direction's
   transmission error, unbiased by the noise (the peak-to-peak of raw noisy samples is not).
5. Each line gets the components whose order (or its 2×) lies within half a bin (1/(2N) order) of it
   (``kinematics.components_at``); none: the line is reported by its order alone.

Lines of the two directions at the same order (within half a bin) are combined into ``te_orders`` (amplitudes
averaged, phases averaged on the circle); a line seen in one direction only is kept with its direction.
Convention: TE = Σ A·sin(k·φ + ϕ) with φ the output angle in rad, k per output revolution, ϕ in degrees.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.interpolate import CubicSpline
from scipy.ndimage import median_filter
from threadpoolctl import threadpool_limits

from tcms_daq.errors import DataFormatError, EvaluationError
from tcms_daq.transmission.kinematics import ComponentOrder, Teeth, components_at, order_table
from tcms_daq.units import ARCSEC_PER_RAD, ARCSEC_PER_REV

DIRECTIONS = ("forward", "reverse")
FALSE_ALARM = 0.01  # chance of a line made of noise alone per spectrum
MAX_LINES = 40
NOISE_WINDOW_BINS = 64  # bins each side of a line for its local noise level
CURVE_POINTS = 2048  # points of the TE curve per revolution handed to the pages


@dataclass(frozen=True)
class TeLine:
    """One harmonic of the transmission error: order per output revolution, amplitude (″), phase (deg, TE =
    A·sin(k·φ + ϕ)), standard uncertainties from the noise around it (k = 1), and the components at that order."""

    order_per_output_rev: float
    amplitude_arcsec: float
    phase_deg: float
    u_amplitude_arcsec: float
    u_phase_deg: float
    u_order: float
    components: tuple[str, ...] = ()
    directions: tuple[str, ...] = DIRECTIONS

    @property
    def component(self) -> str | None:
        """The components' names joined ("crankshaft / cycloid_disc"), or None: the order belongs to no
        component."""
        return " / ".join(self.components) if self.components else None

    def to_dict(self) -> dict[str, Any]:
        return {"order": self.order_per_output_rev, "amplitude_arcsec": self.amplitude_arcsec,
                "phase_deg": self.phase_deg, "component": self.component, "components": list(self.components),
                "u_amplitude_arcsec": self.u_amplitude_arcsec, "u_phase_deg": self.u_phase_deg,
                "u_order": self.u_order, "directions": list(self.directions)}


@dataclass
class TeDirection:
    """The transmission error in one direction of rotation."""

    direction: str
    revolutions: int
    peak_to_peak_arcsec: float
    mean_arcsec: float  # the TE's mean: the twist under the load and the lost motion of this direction
    scale_mismatch_ppm: float  # the trend b removed, in parts per million of the output angle
    noise_amplitude_arcsec: float  # √E|A|² of a noise bin (median over the band)
    lines: list[TeLine]
    phi_start_rad: float
    phi_end_rad: float
    samples: int
    curve_angle_deg: np.ndarray = field(repr=False)  # output angle of the curve, deg, from phi_start
    curve_arcsec: np.ndarray = field(repr=False)  # the measured TE there (trend and mean removed)
    curve_fit_arcsec: np.ndarray = field(repr=False)  # the sum of the lines there
    offset_arcsec: float = 0.0  # φ = θ_in/i + offset: the output encoder's zero against the input's

    @property
    def resolution_orders(self) -> float:
        return 1.0 / self.revolutions

    def to_dict(self, *, curve: bool = False) -> dict[str, Any]:
        out: dict[str, Any] = {
            "revolutions": self.revolutions, "transmission_error_arcsec": self.peak_to_peak_arcsec,
            "mean_arcsec": self.mean_arcsec, "scale_mismatch_ppm": self.scale_mismatch_ppm,
            "noise_amplitude_arcsec": self.noise_amplitude_arcsec, "resolution_orders": self.resolution_orders,
            "samples": self.samples, "phi_start_deg": math.degrees(self.phi_start_rad),
            "phi_end_deg": math.degrees(self.phi_end_rad), "te_orders": [line.to_dict() for line in self.lines]}
        if curve:
            out["curve"] = {"output_angle_deg": self.curve_angle_deg.tolist(), "te_arcsec": self.curve_arcsec.tolist(),
                            "te_fit_arcsec": self.curve_fit_arcsec.tolist()}
        return out


@dataclass
class TeEvaluation:
    """The transmission-error test's results (``to_dict()`` is the JSON form)."""

    transmission_error_arcsec: float  # the larger direction's peak-to-peak
    per_direction: dict[str, TeDirection]
    te_orders: list[TeLine]
    ratio: float
    warnings: list[str] = field(default_factory=list)
    uncertainty: dict[str, Any] = field(default_factory=dict)

    @property
    def hysteresis_arcsec(self) -> float:
        """Forward minus reverse mean TE: the lost motion under the test's light load (″)."""
        return self.per_direction["forward"].mean_arcsec - self.per_direction["reverse"].mean_arcsec

    def to_dict(self, *, curve: bool = False) -> dict[str, Any]:
        return {"method": "transmission-error", "transmission_error_arcsec": self.transmission_error_arcsec,
                "ratio": self.ratio, "hysteresis_arcsec": self.hysteresis_arcsec,
                "te_orders": [line.to_dict() for line in self.te_orders],
                "per_direction": {k: v.to_dict(curve=curve) for k, v in self.per_direction.items()},
                "warnings": list(self.warnings), "uncertainty": self.uncertainty}


# ------------------------------------------------------------------------------------------------- segmentation


def _speed(time_s: np.ndarray, angle: np.ndarray, span: int = 5) -> np.ndarray:
    """Angle rate (units/s) by differences over ``span`` samples each side (quantised encoders at low speed)."""
    n = angle.size
    lo = np.clip(np.arange(n) - span, 0, n - 1)
    hi = np.clip(np.arange(n) + span, 0, n - 1)
    dt = time_s[hi] - time_s[lo]
    return np.where(dt > 0, (angle[hi] - angle[lo]) / np.where(dt > 0, dt, 1.0), 0.0)


def direction_stretches(time_s: np.ndarray, input_angle_arcsec: np.ndarray, share: float = 0.9
                        ) -> dict[str, slice]:
    """The longest stretch of each direction at its running speed (|rate| ≥ ``share`` of the direction's median
    running rate): the samples a turning evaluation uses. Directions not turned are absent."""
    rate = _speed(time_s, input_angle_arcsec)
    top = float(np.max(np.abs(rate), initial=0.0))
    out: dict[str, slice] = {}
    if top <= 0.0:
        return out
    for name, sign in (("forward", 1.0), ("reverse", -1.0)):
        moving = sign * rate > 0.1 * top
        if not moving.any():
            continue
        running = float(np.median(sign * rate[moving]))
        mask = sign * rate >= share * running
        best = _longest_run(mask)
        if best is not None:
            out[name] = best
    return out


def _longest_run(mask: np.ndarray) -> slice | None:
    if not mask.any():
        return None
    edges = np.flatnonzero(np.diff(np.concatenate(([0], mask.astype(np.int8), [0]))))
    starts, ends = edges[::2], edges[1::2]
    k = int(np.argmax(ends - starts))
    return slice(int(starts[k]), int(ends[k]))


# ------------------------------------------------------------------------------------------------- lines


def _design(phi: np.ndarray, orders: list[float]) -> np.ndarray:
    """Columns [1, φ − mean, cos kφ, sin kφ …]."""
    cols = [np.ones_like(phi), phi - phi.mean()]
    for k in orders:
        cols += [np.cos(k * phi), np.sin(k * phi)]
    return np.column_stack(cols)


def _fit(phi: np.ndarray, y: np.ndarray, orders: list[float]) -> tuple[np.ndarray, np.ndarray]:
    """Least squares of y on [1, φ, cos kφ, sin kφ …]: (coefficients, residual)."""
    a = _design(phi, orders)
    coef, *_ = np.linalg.lstsq(a, y, rcond=None)
    return coef, y - a @ coef


def _power(phi: np.ndarray, z: np.ndarray, k: float, base: np.ndarray) -> float:
    """What {cos kφ, sin kφ} take off the residual sum of squares of a fit whose columns span ``base`` (orthonormal)
    and whose residual is z: the columns are made orthogonal to the base first (at low orders a trend and sines of
    neighbouring orders are far from orthogonal to each other over one revolution)."""
    cols = np.column_stack((np.cos(k * phi), np.sin(k * phi)))
    cols -= base @ (base.T @ cols)
    g = cols.T @ cols
    b = cols.T @ z
    try:
        return float(b @ np.linalg.solve(g, b))
    except np.linalg.LinAlgError:
        return 0.0


def _base(phi: np.ndarray, orders: list[float] | None = None) -> np.ndarray:
    """An orthonormal basis of the fit's columns (the constant, the trend and the lines at ``orders``)."""
    q, _ = np.linalg.qr(_design(phi, orders or []))
    return q


def _refine(phi: np.ndarray, z: np.ndarray, k0: float, half_width: float, base: np.ndarray | None = None) -> float:
    """The order near ``k0`` (within ± half_width) whose sinusoid takes most of z's energy (a grid, then a
    parabola through the best point and its neighbours)."""
    base = _base(phi) if base is None else base
    grid = np.linspace(k0 - half_width, k0 + half_width, 13)
    p = np.array([_power(phi, z, k, base) for k in grid])
    j = int(np.argmax(p))
    if 0 < j < grid.size - 1:
        denom = p[j - 1] - 2.0 * p[j] + p[j + 1]
        if denom < 0.0:
            step = grid[1] - grid[0]
            return float(grid[j] + 0.5 * step * (p[j - 1] - p[j + 1]) / denom)
    return float(grid[j])


def _spectrum(z: np.ndarray, max_bin: int) -> np.ndarray:
    """Squared one-sided amplitudes A² of bins 1…max_bin of an evenly sampled record."""
    x = np.fft.rfft(z) / z.size
    return 4.0 * np.abs(x[1:max_bin + 1]) ** 2


def noise_levels(power: np.ndarray, taken: set[int]) -> np.ndarray:
    """E|A|² of the noise at every bin: the running median of the squared amplitudes over ± ``NOISE_WINDOW_BINS``
    (bins of found lines replaced by the overall median) divided by ln 2 (the median of an exponential variable)."""
    masked = power.copy()
    idx = [j for j in taken if 0 <= j < power.size]
    rest = np.delete(power, idx) if idx else power
    if idx:
        masked[idx] = float(np.median(rest)) if rest.size else 0.0
    size = min(2 * NOISE_WINDOW_BINS + 1, power.size if power.size % 2 else power.size - 1)
    level = median_filter(masked, size=max(size, 1), mode="reflect") if power.size > 2 else masked
    return np.maximum(level, 1e-300) / math.log(2.0)


@dataclass(frozen=True)
class _Found:
    orders: list[float]
    coef: np.ndarray
    residual: np.ndarray
    noise_power: list[float]  # E|A|² of the noise at each line


def find_lines(phi_rad: np.ndarray, te_arcsec: np.ndarray, revolutions: int, max_bin: int,
               false_alarm: float = FALSE_ALARM, known_orders: list[float] | None = None, detect: bool = True
               ) -> _Found:
    """The matching pursuit of the module docstring on an evenly sampled record over ``revolutions`` whole output
    revolutions: the orders of the lines (per output revolution), the joint fit's coefficients ([a, b, cos, sin …])
    and residual, and the noise level at each line. ``known_orders``: lines fitted from the start (no detection
    needed: a model's orders); ``detect=False``: those alone (the budgets re-evaluate a perturbed record with the
    orders it found).

    A line is taken at its bin (a line of an integer order over whole revolutions sits on its bin, and sinusoids
    on bins are orthogonal there). A candidate within three bins of a line already found may be that line's leakage
    (it lies between bins): the line moved within half a bin to its best order, without the candidate, is compared
    with the candidate added at its bin, and the better fit wins. At the end, lines with a neighbour within two bins
    or off their bins are refined again with all others fitted (moved only when that explains more than 9 × the
    noise variance), and lines that no longer stand out are dropped."""
    fixed = len(known_orders or [])
    orders: list[float] = list(known_orders or [])
    threshold = math.log(max_bin / false_alarm)
    coef, residual = _fit(phi_rad, te_arcsec, orders)
    # what a refinement must gain (sum of squares) to move a line off its bin: 9 × the noise variance per sample
    min_gain = 9.0 * float(np.median(_spectrum(residual, max_bin))) / math.log(2.0) * residual.size / 4.0
    for _ in range(MAX_LINES if detect else 0):
        power = _spectrum(residual, max_bin)
        taken = _bins(orders, revolutions, power.size)
        ratios = power / noise_levels(power, taken)
        for j in taken:
            ratios[j] = 0.0
        j = int(np.argmax(ratios))
        if not ratios[j] > threshold:
            break
        candidate = (j + 1) / revolutions
        near = [idx for idx in range(fixed, len(orders)) if abs(orders[idx] - candidate) <= 3.0 / revolutions]
        if near:
            # leakage of a neighbour taken at its bin while it lies between bins, or a line of its own? the
            # neighbour refined (no new line) against the candidate added at its bin: the better fit wins
            idx = min(near, key=lambda i: abs(orders[i] - candidate))
            others = orders[:idx] + orders[idx + 1:]
            basis = _base(phi_rad, others)
            rest = te_arcsec - basis @ (basis.T @ te_arcsec)
            moved = _refine(phi_rad, rest, orders[idx], 0.5 / revolutions, basis)
            refined = [*others[:idx], moved, *others[idx:]]
            _, res_refined = _fit(phi_rad, te_arcsec, refined)
            _, res_added = _fit(phi_rad, te_arcsec, [*orders, candidate])
            if float(res_refined @ res_refined) <= float(res_added @ res_added):
                orders = refined
                coef, residual = _fit(phi_rad, te_arcsec, orders)
                continue
        orders.append(candidate)
        coef, residual = _fit(phi_rad, te_arcsec, orders)
    if detect and len(orders) > fixed:
        orders = _refine_off_bin(phi_rad, te_arcsec, orders, revolutions, fixed, min_gain)
        coef, residual = _fit(phi_rad, te_arcsec, orders)
        orders, coef, residual = _drop_insignificant(phi_rad, te_arcsec, orders, coef, residual, revolutions,
                                                     max_bin, threshold, fixed)
    final_power = _spectrum(residual, max_bin)
    levels = noise_levels(final_power, _bins(orders, revolutions, final_power.size))
    noise = [float(levels[min(max(int(round(k * revolutions)) - 1, 0), final_power.size - 1)]) for k in orders]
    return _Found(orders, coef, residual, noise)


def _refine_off_bin(phi_rad: np.ndarray, y: np.ndarray, orders: list[float], revolutions: int, fixed: int,
                    min_gain: float) -> list[float]:
    """Orders with another line within two bins (or taken off their bin) refined again with all other lines and
    the trend fitted: a neighbour one bin away pulls a lone refinement; kept where they are unless moving gains
    more than ``min_gain`` (sum of squares)."""
    orders = list(orders)
    for idx in range(fixed, len(orders)):
        others = orders[:idx] + orders[idx + 1:]
        k0 = orders[idx]
        on_bin = abs(k0 * revolutions - round(k0 * revolutions)) < 1e-9
        if on_bin and not any(abs(k - k0) < 2.0 / revolutions for k in others):
            continue
        basis = _base(phi_rad, others)
        rest = y - basis @ (basis.T @ y)
        k = _refine(phi_rad, rest, k0, 0.5 / revolutions, basis)
        if _power(phi_rad, rest, k, basis) - _power(phi_rad, rest, k0, basis) > min_gain:
            orders[idx] = k
    return orders


def _drop_insignificant(phi_rad: np.ndarray, y: np.ndarray, orders: list[float], coef: np.ndarray,
                        residual: np.ndarray, revolutions: int, max_bin: int, threshold: float, fixed: int = 0
                        ) -> tuple[list[float], np.ndarray, np.ndarray]:
    """Lines whose amplitude in the joint fit no longer stands out of the noise at their order (a line taken early
    that the trend or a neighbour explains better) are dropped, weakest first; a model's orders stay."""
    while len(orders) > fixed:
        levels = noise_levels(_spectrum(residual, max_bin), _bins(orders, revolutions, max_bin))
        weakest, worst = None, math.inf
        for idx in range(fixed, len(orders)):
            amp2 = coef[2 + 2 * idx] ** 2 + coef[3 + 2 * idx] ** 2
            j = min(max(int(round(orders[idx] * revolutions)) - 1, 0), max_bin - 1)
            ratio = amp2 / levels[j]
            if ratio < worst:
                weakest, worst = idx, ratio
        if weakest is None or worst > threshold:
            break
        orders = orders[:weakest] + orders[weakest + 1:]
        coef, residual = _fit(phi_rad, y, orders)
    return orders, coef, residual


def _bins(orders: list[float], revolutions: int, size: int) -> set[int]:
    """The spectrum indices (0-based: bin 1 is index 0) of lines at ``orders``."""
    return {j for k in orders if 0 <= (j := int(round(k * revolutions)) - 1) < size}


# ------------------------------------------------------------------------------------------------- evaluation


@dataclass(frozen=True)
class TeRecord:
    """One direction's transmission error on an even grid of the output angle over whole revolutions: φ (rad, on
    the output encoder's zero), TE (″), the number of revolutions, and the offset that moved φ = θ_in/i onto the
    output encoder (″)."""

    direction: str
    phi_rad: np.ndarray
    te_arcsec: np.ndarray
    revolutions: int
    offset_arcsec: float

    def max_bin(self, max_order: float | None = None) -> int:
        """The highest bin of the band: a quarter of the samples per revolution, or ``max_order``."""
        samples_per_rev = self.phi_rad.size / self.revolutions
        band = samples_per_rev / 4.0 if max_order is None else min(max_order, samples_per_rev / 4.0)
        return max(2, int(band * self.revolutions))


def _record(name: str, phi_arcsec: np.ndarray, te: np.ndarray, offset: float, resample: str) -> TeRecord:
    order = np.argsort(phi_arcsec, kind="stable")
    phi_sorted, te_sorted = phi_arcsec[order], te[order]
    phi_u, inverse = np.unique(phi_sorted, return_inverse=True)
    if phi_u.size < phi_sorted.size:  # repeated input readings (a quantised encoder at low speed): their mean
        te_sorted = np.bincount(inverse, weights=te_sorted) / np.bincount(inverse)
    revolutions = int(math.floor((phi_u[-1] - phi_u[0]) / ARCSEC_PER_REV + 1e-9))
    if revolutions < 1:
        covered = (phi_u[-1] - phi_u[0]) / ARCSEC_PER_REV
        raise EvaluationError(f"transmission error: the {name} rotation covers {covered:.2f} output revolutions at "
                              "its running speed; at least one whole revolution is needed")
    span = revolutions * ARCSEC_PER_REV
    start = phi_u[0] + 0.5 * ((phi_u[-1] - phi_u[0]) - span)  # the central whole revolutions
    inside = (phi_u >= start - 1e-6) & (phi_u <= start + span + 1e-6)
    m = int(np.count_nonzero(inside))
    grid = start + np.arange(m) * (span / m)
    te_grid = (CubicSpline(phi_u, te_sorted)(grid) if resample == "cubic" else np.interp(grid, phi_u, te_sorted))
    return TeRecord(name, grid / ARCSEC_PER_RAD, te_grid, revolutions, offset)


def te_records(time_s: npt.ArrayLike, input_angle_arcsec: npt.ArrayLike, output_angle_arcsec: npt.ArrayLike, *,
               ratio: float, resample: str = "cubic") -> dict[str, TeRecord]:
    """Both directions' transmission error on even grids of the output angle (steps 1–2 of the module docstring).
    Raises EvaluationError when a direction is missing or has less than one whole output revolution."""
    if not ratio > 0:
        raise DataFormatError(f"transmission error: ratio must be > 0 (got {ratio})")
    if resample not in ("cubic", "linear"):
        raise ValueError(f"resample must be 'cubic' or 'linear' (got {resample!r})")
    t, a_in, a_out = te_arrays(time_s, input_angle_arcsec, output_angle_arcsec)
    stretches = direction_stretches(t, a_in)
    missing = [d for d in DIRECTIONS if d not in stretches]
    if missing:
        raise EvaluationError(f"transmission error: no {' and no '.join(missing)} rotation at a steady speed in the "
                              "record (both directions are needed)")
    out = {}
    for name in DIRECTIONS:
        sl = stretches[name]
        phi = a_in[sl] / ratio
        raw = a_out[sl] - phi
        # the output encoder's zero: the median of θ_out − θ_in/i, a scale mismatch b of the encoders (θ_out − θ_in/i
        # = TE + a + b·θ_in/i) taken out first
        trend = np.polyfit(phi - phi.mean(), raw, 1)[0] if phi.size > 2 else 0.0
        offset = float(np.median(raw - trend * phi))
        out[name] = _record(name, phi + offset, raw - offset, offset, resample)
    return out


def line_of(found: _Found, idx: int, revolutions: int, table: list[ComponentOrder] | None, direction: str) -> TeLine:
    """The ``idx``-th line of a pursuit as a TeLine: amplitude and phase from the joint fit, their standard
    uncertainties from the noise level at the line, the components at its order (within half a bin)."""
    k = found.orders[idx]
    c, s = found.coef[2 + 2 * idx], found.coef[3 + 2 * idx]
    amplitude = math.hypot(c, s)
    u_amp = math.sqrt(found.noise_power[idx] / 2.0)
    u_phase = math.degrees(u_amp / amplitude) if amplitude > 0 else 180.0
    u_order = u_amp / max(amplitude, 1e-12) * math.sqrt(3.0) / (math.pi * revolutions)
    names = tuple(r.label for r in components_at(k, 0.5 / revolutions, table)) if table is not None else ()
    return TeLine(k, amplitude, math.degrees(math.atan2(c, s)) % 360.0, u_amp, min(u_phase, 180.0), u_order, names,
                  (direction,))


def evaluate_direction(record: TeRecord, table: list[ComponentOrder] | None, max_order: float | None, false_alarm: float,
               known_orders: list[float] | None, detect: bool) -> TeDirection:
    phi_rad, te_grid, revolutions = record.phi_rad, record.te_arcsec, record.revolutions
    m = phi_rad.size
    span_rad = revolutions * 2.0 * math.pi
    max_bin = record.max_bin(max_order)
    found = find_lines(phi_rad, te_grid, revolutions, max_bin, false_alarm, known_orders, detect)
    lines = sorted((line_of(found, idx, revolutions, table, record.direction) for idx in range(len(found.orders))),
                   key=lambda ln: -ln.amplitude_arcsec)
    fit = _sum_of_lines(phi_rad, lines)
    curve_idx = np.linspace(0, m - 1, min(m, CURVE_POINTS * revolutions)).astype(int)
    measured = te_grid - found.coef[0] - found.coef[1] * (phi_rad - phi_rad.mean())
    dense = np.linspace(phi_rad[0], phi_rad[0] + span_rad,
                        max(4096, int(32 * max((ln.order_per_output_rev for ln in lines), default=1.0) * revolutions)))
    te_dense = _sum_of_lines(dense, lines)
    return TeDirection(
        direction=record.direction, revolutions=revolutions,
        peak_to_peak_arcsec=float(np.max(te_dense) - np.min(te_dense)) if lines else 0.0,
        mean_arcsec=float(np.mean(te_grid)) + record.offset_arcsec,
        scale_mismatch_ppm=float(found.coef[1] * 1e6 / ARCSEC_PER_RAD),
        noise_amplitude_arcsec=math.sqrt(float(np.median(_spectrum(found.residual, max_bin))) / math.log(2.0)),
        lines=lines, phi_start_rad=float(phi_rad[0]), phi_end_rad=float(phi_rad[0] + span_rad),
        samples=m,
        curve_angle_deg=np.degrees(phi_rad[curve_idx] - phi_rad[0]),
        curve_arcsec=measured[curve_idx], curve_fit_arcsec=fit[curve_idx], offset_arcsec=record.offset_arcsec)


def _sum_of_lines(phi_rad: np.ndarray, lines: list[TeLine]) -> np.ndarray:
    out = np.zeros_like(phi_rad)
    for ln in lines:
        out += ln.amplitude_arcsec * np.sin(ln.order_per_output_rev * phi_rad + math.radians(ln.phase_deg))
    return out


def combine_directions(per_direction: dict[str, TeDirection]) -> list[TeLine]:
    """The lines of both directions at one order (within half the coarser bin) as one: the mean of their complex
    amplitudes (a part that changes sign with the direction, e.g. a skew of the angle readings times the speed,
    cancels), the order averaged, uncertainties of the mean; a line of one direction stays as it is."""
    if not per_direction:
        return []
    tolerance = 0.5 / min(d.revolutions for d in per_direction.values())
    pool = [ln for d in per_direction.values() for ln in d.lines]
    pool.sort(key=lambda ln: -ln.amplitude_arcsec)
    out: list[TeLine] = []
    used = [False] * len(pool)
    for i, line in enumerate(pool):
        if used[i]:
            continue
        used[i] = True
        partner = next((j for j in range(i + 1, len(pool)) if not used[j] and pool[j].directions != line.directions
                        and abs(pool[j].order_per_output_rev - line.order_per_output_rev) <= tolerance), None)
        if partner is None:
            out.append(line)
            continue
        used[partner] = True
        a, b = line, pool[partner]
        z = 0.5 * (_phasor(a) + _phasor(b))
        amplitude = abs(z)
        u_amp = 0.5 * math.hypot(a.u_amplitude_arcsec, b.u_amplitude_arcsec)
        out.append(TeLine(0.5 * (a.order_per_output_rev + b.order_per_output_rev), amplitude,
                          math.degrees(math.atan2(z.imag, z.real)) % 360.0, u_amp,
                          min(180.0, math.degrees(u_amp / amplitude)) if amplitude > 0 else 180.0,
                          0.5 * math.hypot(a.u_order, b.u_order), a.components or b.components, DIRECTIONS))
    return sorted(out, key=lambda ln: -ln.amplitude_arcsec)


def _phasor(line: TeLine) -> complex:
    """A·e^{iϕ} of a line (TE = A·sin(kφ + ϕ) = Im(A·e^{iϕ}·e^{ikφ}))."""
    return line.amplitude_arcsec * complex(math.cos(math.radians(line.phase_deg)), math.sin(math.radians(line.phase_deg)))


def te_arrays(time_s: npt.ArrayLike, input_angle_arcsec: npt.ArrayLike, output_angle_arcsec: npt.ArrayLike
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    t = np.asarray(time_s, dtype=float).ravel()
    a_in = np.asarray(input_angle_arcsec, dtype=float).ravel()
    a_out = np.asarray(output_angle_arcsec, dtype=float).ravel()
    if not (t.size == a_in.size == a_out.size):
        raise DataFormatError(f"time_s, input_angle_arcsec and output_angle_arcsec differ in length ({t.size}, "
                              f"{a_in.size}, {a_out.size})")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(a_in)) and np.all(np.isfinite(a_out))):
        raise DataFormatError("transmission error: the arrays hold NaN or infinite values")
    if t.size > 1 and np.any(np.diff(t) <= 0):
        raise DataFormatError("transmission error: time_s must increase")
    return t, a_in, a_out


def evaluate_transmission_error(time_s: npt.ArrayLike, input_angle_arcsec: npt.ArrayLike,
                                output_angle_arcsec: npt.ArrayLike, *, ratio: float, teeth: Teeth | None = None,
                                max_order_per_output_rev: float | None = None, false_alarm: float = FALSE_ALARM,
                                known_orders: dict[str, list[float]] | list[float] | None = None, detect: bool = True,
                                resample: str = "cubic") -> TeEvaluation:
    """The transmission-error test (module docstring). Angles in arcsec (the input's in input arcsec), both
    directions of rotation in one record; ``teeth`` names the orders (None: orders only);
    ``max_order_per_output_rev`` limits the band (default a quarter of the samples per revolution);
    ``known_orders``: orders fitted whether or not they stand out (a model's; a list, or one per direction);
    ``detect=False`` fits those alone; ``resample``: "cubic" (default) or "linear" onto the angle grid. Raises
    EvaluationError when a direction has less than one whole output revolution at its running speed."""
    records = te_records(time_s, input_angle_arcsec, output_angle_arcsec, ratio=ratio, resample=resample)
    table = order_table(teeth) if teeth is not None else None
    per_direction = {}
    with threadpool_limits(limits=1, user_api="blas"):  # many small least-squares fits: threads cost more
        for name, record in records.items():
            known = known_orders.get(name) if isinstance(known_orders, dict) else known_orders
            per_direction[name] = evaluate_direction(record, table, max_order_per_output_rev, false_alarm, known,
                                                     detect)
    warnings = []
    for d in per_direction.values():
        if abs(d.scale_mismatch_ppm) > 50.0:
            warnings.append(f"the output angle runs {d.scale_mismatch_ppm:+.0f} ppm against the input's over the "
                            f"{d.direction} rotation (encoder scale or ratio): removed as a trend, check the "
                            "encoders and the ratio")
    return TeEvaluation(max(d.peak_to_peak_arcsec for d in per_direction.values()), per_direction,
                        combine_directions(per_direction), float(ratio), warnings)

"""Starting torque, no-load running torque and efficiency (GB/T 35089 §7): pure functions on the station's arrays.

Conventions: torques in N·m (the input torque is the drive's torque on the input shaft, positive turning it
forward; the output torque is the loader's torque on the output, positive towards the output's positive direction,
so a braking load on a forward rotation reads negative), angles in arcsec (the input's in input arcsec), speeds in
rpm of the input shaft.

* **Starting torque** (input torque ramped slowly in torque mode until the input turns): per ramp, the instant the
  input starts to turn is fitted, not detected — a detection threshold comes late by the time the angle needs to
  cross it, and the torque has risen meanwhile. After breakaway the input angle grows as a(t − t0)² + c(t − t0)³
  (the excess torque at breakaway accelerates it, the ramp adds the cubic part); t0 is the least-squares onset over
  the first samples of the motion, the starting torque the ramp's torque at t0 (a line fitted to the ramp before
  it: the torque's noise averages out). Per direction, the mean over the ramps.
* **No-load running torque** (constant input speeds, no load, both directions): per speed and direction the mean
  input torque over whole input revolutions of the steady stretch (a ripple locked to the input's rotation
  averages out); the running torque at a speed is half the difference of the two directions' means, in which the
  torque reading's zero cancels.
* **Efficiency** (the input at rated speed, the loader braking with rated torque): per direction the output work
  over the input work, −∫T_out dθ_out / ∫T_in dθ_in, over whole input revolutions of the steady stretch.

Each evaluation keeps its blocks (ramps, or whole-revolution blocks of a stretch): their scatter is the Type A of
the budgets (``tcms_daq.uncertainty.station``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from tcms_daq.analysis.noise import white_noise_std
from tcms_daq.errors import DataFormatError, EvaluationError
from tcms_daq.transmission.te import _speed, direction_stretches
from tcms_daq.units import ARCSEC_PER_RAD, ARCSEC_PER_REV

MIN_BLOCKS = 8
DIRECTION_SIGN = {"forward": 1.0, "reverse": -1.0}


def _arrays(*arrays: npt.ArrayLike, names: Sequence[str]) -> list[np.ndarray]:
    out = [np.asarray(a, dtype=float).ravel() for a in arrays]
    if len({a.size for a in out}) != 1:
        raise DataFormatError(f"{', '.join(names)} differ in length ({', '.join(str(a.size) for a in out)})")
    if not all(np.all(np.isfinite(a)) for a in out):
        raise DataFormatError(f"{', '.join(names)}: NaN or infinite values")
    if out[0].size > 1 and np.any(np.diff(out[0]) <= 0):
        raise DataFormatError("time_s must increase")
    return out


def _mean_and_blocks(values: np.ndarray, blocks: int) -> tuple[float, list[float]]:
    parts = np.array_split(values, blocks)
    return float(np.mean(values)), [float(np.mean(p)) for p in parts if p.size]


# ------------------------------------------------------------------------------------------------- starting torque


@dataclass(frozen=True)
class Breakaway:
    """One ramp: the direction, the starting torque (N·m, magnitude), the fitted onset time (s), the ramp rate
    (N·m/s), the samples the onset fit used and the sample period there (s)."""

    direction: str
    torque_nm: float
    onset_s: float
    rate_nm_per_s: float
    fit_samples: int
    sample_period_s: float


@dataclass
class StartingTorqueEvaluation:
    """``starting_torque_nm`` per direction (mean over its ramps), the larger as the result."""

    per_direction: dict[str, float]
    ramps: list[Breakaway]
    warnings: list[str] = field(default_factory=list)
    uncertainty: dict[str, Any] = field(default_factory=dict)

    @property
    def starting_torque_nm(self) -> float:
        return max(self.per_direction.values())

    def values(self) -> dict[str, float]:
        """The results that get a budget, by name."""
        out = {"starting_torque_nm": self.starting_torque_nm}
        out.update({f"{d}_starting_torque_nm": v for d, v in self.per_direction.items()})
        return out

    def blocks(self, name: str) -> list[float]:
        direction = name.split("_")[0]
        if direction in DIRECTION_SIGN:
            return [r.torque_nm for r in self.ramps if r.direction == direction]
        top = max(self.per_direction, key=lambda d: self.per_direction[d])
        return [r.torque_nm for r in self.ramps if r.direction == top]

    def to_dict(self) -> dict[str, Any]:
        return {"method": "starting-torque", "starting_torque_nm": self.starting_torque_nm,
                "per_direction": {d: {"starting_torque_nm": v} for d, v in self.per_direction.items()},
                "ramps": [asdict(r) for r in self.ramps], "warnings": list(self.warnings),
                "uncertainty": self.uncertainty}


def _episodes(torque: np.ndarray, level: float, smooth: int = 25) -> list[tuple[int, int, float]]:
    """(start, end, sign) of each stretch where the torque (a moving mean over ``smooth`` samples, so that noise
    near the level does not cut a slow ramp into pieces) stays beyond ``level`` with one sign and reaches at least
    three times it."""
    kernel = np.ones(min(smooth, max(1, torque.size))) / min(smooth, max(1, torque.size))
    smoothed = np.convolve(torque, kernel, mode="same")
    out = []
    for sign in (1.0, -1.0):
        mask = sign * smoothed > level
        edges = np.flatnonzero(np.diff(np.concatenate(([0], mask.astype(np.int8), [0]))))
        out += [(int(a), int(b), sign) for a, b in zip(edges[::2], edges[1::2], strict=True)
                if b - a > 10 and np.max(sign * smoothed[a:b]) > 3.0 * level]
    return sorted(out)


def _onset(t: np.ndarray, x: np.ndarray, first: int, sign: float, threshold: float) -> tuple[float, int]:
    """Fitted onset time of the motion x (displacement from rest, input arcsec) that first leaves ±threshold at
    index ``first``: least squares of x = a(t − t0)² + c(t − t0)³ for t ≥ t0 (0 before) over the samples until the
    displacement reaches 30 thresholds (at least 12 samples), t0 on a grid within the 20 samples before ``first``
    refined by a parabola."""
    n = x.size
    far = np.flatnonzero(sign * x[first:] > 30.0 * threshold)
    last = min(n, first + max(12, int(far[0]) + 1 if far.size else 12))
    lo = max(0, first - 20)
    tt, xx = t[lo:last], x[lo:last]
    grid = np.linspace(t[lo], t[first], 81)

    def rss(t0: float) -> float:
        s = np.clip(tt - t0, 0.0, None)
        a = np.column_stack((s**2, s**3))
        coef, *_ = np.linalg.lstsq(a, xx, rcond=None)
        return float(np.sum((xx - a @ coef) ** 2))

    values = np.array([rss(g) for g in grid])
    j = int(np.argmin(values))
    t0 = float(grid[j])
    if 0 < j < grid.size - 1:
        denom = values[j - 1] - 2 * values[j] + values[j + 1]
        if denom > 0:
            t0 += 0.5 * (grid[1] - grid[0]) * (values[j - 1] - values[j + 1]) / denom
    return t0, last - lo


def evaluate_starting_torque(time_s: npt.ArrayLike, input_torque_nm: npt.ArrayLike,
                             input_angle_arcsec: npt.ArrayLike) -> StartingTorqueEvaluation:
    """The starting torque of each ramp and direction (module docstring). Raises EvaluationError when a direction
    has no ramp with motion."""
    t, torque, angle = _arrays(time_s, input_torque_nm, input_angle_arcsec,
                               names=("time_s", "input_torque_nm", "input_angle_arcsec"))
    sigma_t = white_noise_std(torque)
    sigma_a = white_noise_std(angle)
    steps = np.abs(np.diff(angle))
    quantum = float(np.min(steps[steps > 0])) if np.any(steps > 0) else 0.0
    threshold = max(6.0 * sigma_a, 2.5 * quantum, 1e-6)
    level = max(8.0 * sigma_t, 0.02 * float(np.max(np.abs(torque), initial=0.0)))
    ramps: list[Breakaway] = []
    warnings: list[str] = []
    for start, end, sign in _episodes(torque, level):
        seg_a = angle[start:end]
        rest = float(np.median(seg_a[: max(5, (end - start) // 10)]))
        moved = np.flatnonzero(np.abs(seg_a - rest) > threshold)
        # the first sample from which the angle stays away from rest for 5 samples
        first = next((int(k) for k in moved if np.all(np.abs(seg_a[k:k + 5] - rest) > threshold)), None)
        direction = "forward" if sign > 0 else "reverse"
        if first is None:
            warnings.append(f"a {direction} ramp to {sign * np.max(sign * torque[start:end]):.3g} N·m did not turn "
                            "the input")
            continue
        t0, used = _onset(t[start:end], seg_a - rest, first, sign, threshold)
        k0 = start + int(np.searchsorted(t[start:end], t0))
        before = slice(start + max(0, (k0 - start) // 5), max(k0, start + 2))
        if before.stop - before.start < 3:
            warnings.append(f"a {direction} ramp turned the input at once: its torque before the motion is too "
                            "short to fit")
            continue
        slope, intercept = np.polyfit(t[before], torque[before], 1)
        period = float(np.median(np.diff(t[before]))) if before.stop - before.start > 1 else 0.0
        ramps.append(Breakaway(direction, float(abs(slope * t0 + intercept)), t0, float(abs(slope)), used, period))
    per_direction = {}
    for direction in ("forward", "reverse"):
        values = [r.torque_nm for r in ramps if r.direction == direction]
        if not values:
            raise EvaluationError(f"starting torque: no {direction} ramp turned the input")
        per_direction[direction] = float(np.mean(values))
    return StartingTorqueEvaluation(per_direction, ramps, warnings)


# ------------------------------------------------------------------------------------------------- no-load torque


@dataclass(frozen=True)
class SteadyStretch:
    """A steady stretch at one speed and direction: its mean input speed (rpm, signed), mean input torque (N·m),
    the means of its blocks (N·m) and how many whole input revolutions it spans."""

    direction: str
    speed_rpm: float
    torque_nm: float
    block_torques_nm: list[float]
    revolutions: int


@dataclass
class NoLoadTorqueEvaluation:
    """``no_load_torque_nm`` per commanded speed (rpm): half the difference of the two directions' mean input
    torques (the zero of the reading cancels); the stretches behind them."""

    per_speed: dict[float, float]
    stretches: list[SteadyStretch]
    temperature_c: float | None = None
    warnings: list[str] = field(default_factory=list)
    uncertainty: dict[str, Any] = field(default_factory=dict)

    def values(self) -> dict[str, float]:
        out = {}
        for speed, value in self.per_speed.items():
            out[f"no_load_torque_nm@{speed:g}rpm"] = value
            for s in self.stretches:
                if abs(abs(s.speed_rpm) - speed) <= 0.05 * speed:
                    out[f"{s.direction}_no_load_torque_nm@{speed:g}rpm"] = abs(s.torque_nm)
        return out

    def blocks(self, name: str) -> list[float]:
        key, _, speed_text = name.partition("@")
        speed = float(speed_text.removesuffix("rpm"))
        pair = {s.direction: s for s in self.stretches if abs(abs(s.speed_rpm) - speed) <= 0.05 * speed}
        direction = key.split("_")[0]
        if direction in pair:
            return [abs(b) for b in pair[direction].block_torques_nm]
        fwd, rev = pair["forward"].block_torques_nm, pair["reverse"].block_torques_nm
        m = min(len(fwd), len(rev))
        return [0.5 * (a - b) for a, b in zip(fwd[:m], rev[:m], strict=True)]

    def to_dict(self) -> dict[str, Any]:
        return {"method": "no-load-torque",
                "no_load_torque_nm": {f"{k:g}": v for k, v in self.per_speed.items()},
                "stretches": [asdict(s) for s in self.stretches], "temperature_c": self.temperature_c,
                "warnings": list(self.warnings), "uncertainty": self.uncertainty}


def _steady(t: np.ndarray, speed_rpm: np.ndarray, target_rpm: float, settle_s: float, tolerance: float
            ) -> slice | None:
    """The longest stretch within ``tolerance`` (share) of ``target_rpm`` (signed), its first ``settle_s`` left
    out."""
    mask = np.abs(speed_rpm - target_rpm) <= tolerance * abs(target_rpm)
    if not mask.any():
        return None
    edges = np.flatnonzero(np.diff(np.concatenate(([0], mask.astype(np.int8), [0]))))
    starts, ends = edges[::2], edges[1::2]
    k = int(np.argmax(ends - starts))
    a = int(np.searchsorted(t, t[starts[k]] + settle_s))
    return slice(a, int(ends[k])) if ends[k] - a > 10 else None


def _whole_revolutions(angle: np.ndarray, sl: slice) -> tuple[slice, int]:
    """The part of ``sl`` spanning the largest whole number of input revolutions (at least the stretch when it
    spans less than one)."""
    a = angle[sl]
    turns = abs(a[-1] - a[0]) / ARCSEC_PER_REV
    whole = int(math.floor(turns))
    if whole < 1:
        return sl, 0
    target = whole * ARCSEC_PER_REV
    end = int(np.searchsorted(np.abs(a - a[0]), target))
    return slice(sl.start, sl.start + max(end, 2)), whole


def evaluate_no_load_torque(time_s: npt.ArrayLike, input_torque_nm: npt.ArrayLike, input_angle_arcsec: npt.ArrayLike,
                            *, speeds_rpm: Sequence[float], settle_s: float = 0.3, tolerance: float = 0.03,
                            temperature_c: npt.ArrayLike | None = None) -> NoLoadTorqueEvaluation:
    """The no-load running torque at each commanded input speed (module docstring): each speed must have been run in
    both directions. ``temperature_c``: the unit's temperature over the record (its mean is reported)."""
    t, torque, angle = _arrays(time_s, input_torque_nm, input_angle_arcsec,
                               names=("time_s", "input_torque_nm", "input_angle_arcsec"))
    speed = _speed(t, angle) / ARCSEC_PER_REV * 60.0
    stretches: list[SteadyStretch] = []
    per_speed: dict[float, float] = {}
    warnings: list[str] = []
    for n in speeds_rpm:
        n = abs(float(n))
        pair: dict[str, SteadyStretch] = {}
        for direction, sign in DIRECTION_SIGN.items():
            sl = _steady(t, speed, sign * n, settle_s, tolerance)
            if sl is None:
                raise EvaluationError(f"no-load torque: no steady {direction} stretch at {n:g} rpm")
            sl, revs = _whole_revolutions(angle, sl)
            if revs == 0:
                warnings.append(f"the {direction} stretch at {n:g} rpm spans less than one input revolution")
            blocks = max(2, min(MIN_BLOCKS, revs)) if revs >= 2 else MIN_BLOCKS
            mean, block_means = _mean_and_blocks(torque[sl], blocks)
            pair[direction] = SteadyStretch(direction, float(np.mean(speed[sl])), mean, block_means, revs)
        stretches += list(pair.values())
        per_speed[n] = 0.5 * (pair["forward"].torque_nm - pair["reverse"].torque_nm)
    temp = None if temperature_c is None else float(np.mean(np.asarray(temperature_c, dtype=float)))
    return NoLoadTorqueEvaluation(per_speed, stretches, temp, warnings)


# ------------------------------------------------------------------------------------------------- efficiency


@dataclass(frozen=True)
class EfficiencyDirection:
    """One direction: efficiency (output work / input work), its blocks', the mean input speed (rpm), the mean
    torques (N·m, magnitudes) and the whole input revolutions evaluated."""

    efficiency: float
    block_efficiencies: list[float]
    input_speed_rpm: float
    input_torque_nm: float
    output_torque_nm: float
    revolutions: int


@dataclass
class EfficiencyEvaluation:
    per_direction: dict[str, EfficiencyDirection]
    warnings: list[str] = field(default_factory=list)
    uncertainty: dict[str, Any] = field(default_factory=dict)

    def values(self) -> dict[str, float]:
        return {f"{d}_efficiency": v.efficiency for d, v in self.per_direction.items()}

    def blocks(self, name: str) -> list[float]:
        return list(self.per_direction[name.split("_")[0]].block_efficiencies)

    def to_dict(self) -> dict[str, Any]:
        return {"method": "efficiency",
                "efficiency": {d: v.efficiency for d, v in self.per_direction.items()},
                "per_direction": {d: asdict(v) for d, v in self.per_direction.items()},
                "warnings": list(self.warnings), "uncertainty": self.uncertainty}


def _work(torque: np.ndarray, angle_arcsec: np.ndarray) -> float:
    """∫T dθ (J) by the trapezoid rule."""
    return float(np.sum(0.5 * (torque[1:] + torque[:-1]) * np.diff(angle_arcsec)) / ARCSEC_PER_RAD)


def evaluate_efficiency(time_s: npt.ArrayLike, input_torque_nm: npt.ArrayLike, input_angle_arcsec: npt.ArrayLike,
                        output_torque_nm: npt.ArrayLike, output_angle_arcsec: npt.ArrayLike, *,
                        settle_s: float = 0.5) -> EfficiencyEvaluation:
    """Efficiency per direction (module docstring) from one record with both directions at a steady input speed
    under a braking load."""
    t, t_in, a_in, t_out, a_out = _arrays(
        time_s, input_torque_nm, input_angle_arcsec, output_torque_nm, output_angle_arcsec,
        names=("time_s", "input_torque_nm", "input_angle_arcsec", "output_torque_nm", "output_angle_arcsec"))
    stretches = direction_stretches(t, a_in, share=0.97)
    out: dict[str, EfficiencyDirection] = {}
    warnings: list[str] = []
    for direction in ("forward", "reverse"):
        if direction not in stretches:
            raise EvaluationError(f"efficiency: no steady {direction} rotation in the record")
        sl = stretches[direction]
        sl = slice(int(np.searchsorted(t, t[sl.start] + settle_s)), sl.stop)
        if sl.stop - sl.start < 20:
            raise EvaluationError(f"efficiency: the steady {direction} stretch is shorter than the settling time")
        sl, revs = _whole_revolutions(a_in, sl)
        if revs < MIN_BLOCKS:
            warnings.append(f"the {direction} stretch spans {revs} input revolutions (fewer than {MIN_BLOCKS}: the "
                            "blocks are not whole revolutions)")
        w_in, w_out = _work(t_in[sl], a_in[sl]), -_work(t_out[sl], a_out[sl])
        if not w_in > 0 or not w_out > 0:
            raise EvaluationError(f"efficiency: in the {direction} stretch the input does not drive a braking load "
                                  f"(input work {w_in:.3g} J, output work {w_out:.3g} J)")
        idx = np.arange(sl.start, sl.stop)
        blocks = []
        for part in np.array_split(idx, MIN_BLOCKS):
            if part.size > 2:
                blocks.append(-_work(t_out[part], a_out[part]) / _work(t_in[part], a_in[part]))
        speed = (a_in[sl.stop - 1] - a_in[sl.start]) / (t[sl.stop - 1] - t[sl.start]) / ARCSEC_PER_REV * 60.0
        out[direction] = EfficiencyDirection(w_out / w_in, blocks, float(speed), float(abs(np.mean(t_in[sl]))),
                                             float(abs(np.mean(t_out[sl]))), revs)
    return EfficiencyEvaluation(out, warnings)

"""Does what remains look like noise? The verdict of a discrepancy analysis, and where the rest is.

The workflow names catalogue effects; this module says whether they are the whole story (DESIGN §8). Pure
numpy on the aligned design data and two residuals (″): before (measured − simulated) and after
(measured − re-simulated with the named effects).

* **Noise floor**, estimated without any model: the sensor noise is white and the discrepancies the bench
  produces are smooth at the sample spacing, so the second differences of the residual carry the noise
  alone, var(Δ²r) = 6 σ². A median absolute deviation keeps steps and reversals from inflating it.
* **Structure**: the residual's means in bins of time, of torque per load direction, of angle, of the angle
  within the encoder's signal period and per loop. Under "noise only" each set of n_b-weighted squared bin
  means is χ² with (bins − 1) degrees of freedom; a set shows structure when it is both significant
  (z > ``SIGNIFICANCE_Z``) and material (its structured RMS ≥ ``MATERIAL_FRACTION`` of the noise: real
  sensor noise is not perfectly white, so significance alone would call correlated noise structure).
  Isolated spikes (a reading far from both neighbours) are material when their variance is; the residual's
  RMS against the noise floor is a backstop for anything else.
* **Verdict**: ``consistent`` (nothing beyond noise before any effect), ``explained`` (effects named, what
  remains is noise), ``partially_explained`` (the names remove at least half of the structured variance,
  the rest is structured), ``unexplained`` (nothing named, or the names remove less than half). Names are
  provisional when structure remains (``partially_explained``, ``unexplained``).
* **What remains** (``unexplained`` block): the time spans whose mean residual stands out, with their torque
  range and load direction; the size; and the shape that best describes it — a step or a ramp in time, a
  saturation at one end of the angle, a change of the loop's width (direction-odd), a periodicity in angle or
  time, or spikes — with how much of the remaining structured variance that shape accounts for.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.signal import lfilter

from tcms_daq.analysis.notices import Notice, notices_of
from tcms_daq.discrepancy.design import DesignData, branch_starts, reversals
from tcms_daq.discrepancy.localise import angle_rate, equal_count_bins, periodogram, time_lines

SIGNIFICANCE_Z = 5.0  # χ² excess in standard deviations, per bin set
MATERIAL_FRACTION = 0.35  # structured RMS / noise floor below which structure is immaterial (adds < 6 % RMS)
RMS_TOLERANCE = 1.5  # residual RMS / noise floor: a backstop for what neither bins nor spikes see
SHARE_FOR_PARTIAL = 0.5  # structured variance the names must remove for "partially explained"
SHAPE_MIN_FRACTION = 0.4  # a shape must account for this share of the remaining structure to be named
SPIKE_Z = 6.0

VERDICTS = ("consistent", "explained", "partially_explained", "unexplained")


def noise_floor_arcsec(residual_arcsec: np.ndarray, time_s: np.ndarray | None = None) -> float:
    """σ of the white noise in ``residual_arcsec`` (rows in time order) from its second differences (robust).

    With ``time_s`` (evenly sampled), coherent sinusoids in time (a vibration) are removed first: a line near the
    sampling rate's range is not smooth at the sample spacing and would otherwise be counted as noise."""
    r = np.asarray(residual_arcsec, dtype=float)
    if len(r) < 5:
        return float("nan")
    if time_s is not None:
        t = np.asarray(time_s, dtype=float) - float(time_s[0])
        for period, amplitude, phase in time_lines(time_s, r):
            r = r - amplitude * np.sin(2 * math.pi * t / period + phase)
    d2 = r[2:] - 2.0 * r[1:-1] + r[:-2]
    mad = float(np.median(np.abs(d2 - np.median(d2))))
    return 1.4826 * mad / math.sqrt(6.0)


@dataclass(frozen=True)
class BinTest:
    """χ² of a residual's bin means against white noise of σ = the noise floor."""

    axis: str
    bins: int
    z: float  # (χ² − dof) / √(2 dof)
    structured_rms_arcsec: float

    def shows_structure(self, noise_arcsec: float) -> bool:
        return self.z > SIGNIFICANCE_Z and self.structured_rms_arcsec >= MATERIAL_FRACTION * noise_arcsec

    def to_dict(self) -> dict[str, Any]:
        return {"axis": self.axis, "bins": self.bins, "z": self.z,
                "structured_rms_arcsec": self.structured_rms_arcsec}


def _bin_test(axis: str, index: np.ndarray, r: np.ndarray, noise: float) -> BinTest | None:
    counts = np.bincount(index).astype(float)
    used = counts > 0
    bins = int(used.sum())
    if bins < 2 or not noise > 0:
        return None
    means = np.bincount(index, weights=r)[used] / counts[used]
    chi2 = float(np.sum(counts[used] * (means - r.mean()) ** 2) / noise**2)
    dof = bins - 1
    z = (chi2 - dof) / math.sqrt(2.0 * dof)
    structured = math.sqrt(max(0.0, chi2 - dof) * noise**2 / len(r))
    return BinTest(axis, bins, float(z), float(structured))


def _time_bins(n: int) -> int:
    return int(np.clip(n // 40, 8, 60))


def bin_tests(data: DesignData, residual: np.ndarray, noise: float) -> list[BinTest]:
    """The structure tests of ``residual`` (see the module docstring)."""
    r = np.asarray(residual, dtype=float)
    n = len(r)
    order_axis = data.time_s if data.has_time else np.arange(n, dtype=float)
    sets: list[tuple[str, np.ndarray]] = [("time" if data.has_time else "sample", equal_count_bins(order_axis, _time_bins(n)))]
    up = data.direction > 0
    torque_bins = equal_count_bins(data.torque_nm, 12)
    sets.append(("torque_by_direction", torque_bins * 2 + up.astype(int)))
    sets.append(("angle", equal_count_bins(data.sim_angle_arcsec, 24)))
    if data.signal_period_arcsec > 0:
        sets.append(("angle_in_signal_period",
                     equal_count_bins(np.mod(data.sim_angle_arcsec, data.signal_period_arcsec), 16)))
    _, groups = np.unique(data.groups, return_inverse=True)
    if groups.max(initial=0) >= 1:
        sets.append((f"per_{data.group_kind.rstrip('s')}", groups))
    tests = [_bin_test(axis, index, r, noise) for axis, index in sets]
    return [t for t in tests if t is not None]


def near_reversals(direction: np.ndarray, rows: int = 3) -> np.ndarray:
    """Rows within ``rows`` samples of a load reversal (where backlash makes the angle jump legitimately)."""
    n = len(direction)
    mask = np.zeros(n, dtype=bool)
    for i in reversals(direction):
        mask[max(0, i - rows):i + rows + 1] = True
    return mask


def isolated_spikes(residual: np.ndarray, noise: float, direction: np.ndarray | None = None
                    ) -> tuple[np.ndarray, np.ndarray]:
    """(mask of isolated spikes, each sample's distance from the mean of its neighbours ″): a spike is a
    sample farther than ``SPIKE_Z`` noise SDs from both neighbours' mean and a local peak of that distance
    (a spike's neighbours see half of it), away from the load reversals of ``direction``."""
    r = np.asarray(residual, dtype=float)
    n = len(r)
    local = np.zeros(n)
    if n < 3 or not noise > 0:
        return np.zeros(n, dtype=bool), local
    local[1:-1] = r[1:-1] - 0.5 * (r[:-2] + r[2:])
    size = np.abs(local)
    peak = np.zeros(n, dtype=bool)
    peak[1:-1] = (size[1:-1] >= size[:-2]) & (size[1:-1] >= size[2:])
    spikes = peak & (size > SPIKE_Z * noise * math.sqrt(1.5))
    if direction is not None:
        spikes &= ~near_reversals(direction)
    return spikes, local


@dataclass(frozen=True)
class Structure:
    """What a residual holds beyond the noise floor."""

    rms_arcsec: float
    noise_arcsec: float
    tests: list[BinTest]
    spike_count: int = 0
    spike_rms_arcsec: float = 0.0

    @property
    def excess_variance(self) -> float:
        """Variance beyond the noise (″²), ≥ 0."""
        return max(0.0, self.rms_arcsec**2 - self.noise_arcsec**2)

    @property
    def structured_rms_arcsec(self) -> float:
        return math.sqrt(self.excess_variance)

    @property
    def present(self) -> bool:
        if not self.noise_arcsec > 0:
            return self.rms_arcsec > 0
        return (self.rms_arcsec > RMS_TOLERANCE * self.noise_arcsec
                or any(t.shows_structure(self.noise_arcsec) for t in self.tests)
                or self.spike_rms_arcsec >= MATERIAL_FRACTION * self.noise_arcsec)

    def to_dict(self) -> dict[str, Any]:
        return {"rms_arcsec": self.rms_arcsec, "structured_rms_arcsec": self.structured_rms_arcsec,
                "present": self.present,
                "axes_with_structure": [t.axis for t in self.tests if t.shows_structure(self.noise_arcsec)],
                "spikes": self.spike_count, "spike_rms_arcsec": self.spike_rms_arcsec,
                "tests": [t.to_dict() for t in self.tests]}


def structure(data: DesignData, residual: np.ndarray, noise: float) -> Structure:
    r = np.asarray(residual, dtype=float) - float(np.mean(residual))
    spikes, local = isolated_spikes(r, noise, data.direction)
    spike_rms = math.sqrt(float(np.sum(local[spikes] ** 2)) / len(r)) if len(r) else 0.0
    return Structure(float(np.sqrt(np.mean(r**2))), noise, bin_tests(data, r, noise), int(spikes.sum()), spike_rms)


# -- what remains: where, how large, what shape -----------------------------------------------------------


class _ShapeFit:
    """Least-squares fits of a candidate shape, added to the named effects, to the residual before them.

    ``before`` = measured − simulated, ``fitted`` = what the named effects predict (``before − after``). Each
    shape is fitted together with a constant and a free multiple of ``fitted`` (a shape may replace part of a
    provisional name, e.g. a step that a drift approximated); its gain is the variance it removes from
    ``after``, in ″².
    """

    def __init__(self, before: np.ndarray, fitted: np.ndarray):
        self.before = before
        self.fitted = fitted
        after = before - fitted
        self.baseline = float(np.mean((after - after.mean()) ** 2))
        self.has_fitted = bool(np.any(fitted != fitted[0])) if len(fitted) else False

    def gain(self, *basis: np.ndarray) -> tuple[float, np.ndarray]:
        cols = [np.ones(len(self.before))]
        if self.has_fitted:
            cols.append(self.fitted)
        cols.extend(basis)
        a = np.column_stack(cols)
        coef, *_ = np.linalg.lstsq(a, self.before, rcond=None)
        residual = self.before - a @ coef
        return self.baseline - float(np.mean(residual**2)), coef[-len(basis):]


def _step_break(t: np.ndarray, r: np.ndarray) -> float | None:
    """The time of the single break that best splits ``r`` into two constant levels (None if none fits)."""
    order = np.argsort(t, kind="stable")
    ts, csum = t[order], np.cumsum(r[order] - r.mean())
    n = len(r)
    best: tuple[float, float] | None = None
    for cut in np.unique(np.quantile(t, np.linspace(0.02, 0.98, 97))):
        k = int(np.searchsorted(ts, cut))
        if 0 < k < n:
            gain = csum[k - 1] ** 2 / k + csum[k - 1] ** 2 / (n - k)
            if best is None or gain > best[0]:
                best = (gain, float(cut))
    return None if best is None else best[1]


MAX_STEPS = 6


STEP_WINDOW = 25  # samples each side of a candidate step


def _steps(t: np.ndarray, r: np.ndarray, noise: float, direction: np.ndarray | None = None) -> list[float]:
    """Every step in ``r`` (rows in time order), each located: the jump between the medians of the
    ``STEP_WINDOW`` samples after and before each row (a ramp or a slow shape moves them little), its local maxima at
    least a window apart, kept when the jump is at least twice the noise, and not at a load reversal (where a loop
    of another shape jumps too); at most ``MAX_STEPS``, the largest first; their times in time order."""
    n, w = len(r), STEP_WINDOW
    if n < 4 * w:
        return []
    x = np.asarray(r, dtype=float)
    windows = np.lib.stride_tricks.sliding_window_view(x, w)
    med = np.median(windows, axis=1)  # med[i] = median of x[i:i + w]
    jump = np.zeros(n)
    jump[w:n - w + 1] = med[w:] - med[:n - 2 * w + 1]
    threshold = max(2.0 * noise, 8.0 * noise / math.sqrt(w))
    if direction is not None:
        for i in reversals(direction):
            jump[max(0, i - w // 2):i + w // 2] = 0.0
    cuts: list[float] = []
    mag = np.abs(jump)
    for _ in range(MAX_STEPS):
        i = int(np.argmax(mag))
        if mag[i] < threshold:
            break
        cuts.append(float(t[i]))
        mag[max(0, i - w):i + w] = 0.0
    return sorted(cuts)


def torque_windows(data: DesignData, r: np.ndarray, noise: float, limit: int = 4) -> list[dict[str, Any]]:
    """Torque windows, per load direction, whose mean residual stands out (≥ 4 standard errors and ≥ ¼ of the
    noise): a dead zone, an effect on one side or in one direction. Each with its direction, torque range, mean and
    whether the other direction shows it over the same torque range (``one_sided``)."""
    found: list[tuple[float, dict[str, Any]]] = []
    flagged_by: dict[int, list[tuple[float, float]]] = {}
    for sign, label in ((1, "loading"), (-1, "unloading")):
        rows = np.flatnonzero(data.direction == sign)
        if len(rows) < 40:
            continue
        index = equal_count_bins(data.torque_nm[rows], min(40, max(8, len(rows) // 50)))
        counts = np.bincount(index).astype(float)
        means = np.bincount(index, weights=r[rows]) / np.maximum(counts, 1)
        flagged = (np.abs(means) >= 4 * noise / np.sqrt(np.maximum(counts, 1))) & (np.abs(means) >= 0.25 * noise)
        b = 0
        while b < len(flagged):
            if not flagged[b]:
                b += 1
                continue
            e = b
            while e + 1 < len(flagged) and flagged[e + 1] and np.sign(means[e + 1]) == np.sign(means[b]):
                e += 1
            sel = rows[(index >= b) & (index <= e)]
            lo, hi = float(data.torque_nm[sel].min()), float(data.torque_nm[sel].max())
            window: dict[str, Any] = {"direction": label, "torque_range_nm": [lo, hi],
                                      "mean_arcsec": float(r[sel].mean()),
                                      "share_of_samples": float(len(sel) / len(r))}
            flagged_by.setdefault(sign, []).append((lo, hi))
            found.append((float(np.sum(np.abs(r[sel]))), window))
            b = e + 1
    for _, w in found:
        sign = 1 if w["direction"] == "loading" else -1
        lo, hi = w["torque_range_nm"]
        w["one_sided"] = not any(a < hi and b > lo for a, b in flagged_by.get(-sign, []))
    found.sort(key=lambda x: -x[0])
    return [w for _, w in found[:limit]]


def _after_reversal(data: DesignData, fit: _ShapeFit) -> list[dict[str, Any]]:
    """A direction-odd transition that decays after each load reversal — over torque travelled (a friction
    loop of another shape or width) or over time (creep, relaxation) — at the best of a few scales."""
    n = len(data.direction)
    starts = branch_starts(data.direction)
    last = starts[np.searchsorted(starts, np.arange(n), side="right") - 1]
    sign = data.direction.astype(float)
    torque_span = float(np.ptp(data.torque_nm))
    out = []
    travelled = np.abs(data.torque_nm - data.torque_nm[last])
    candidates: list[tuple[str, str, np.ndarray, np.ndarray]] = []
    if torque_span > 0:
        scales = torque_span * np.geomspace(0.005, 0.5, 13)
        candidates.append(("torque", "torque_scale_nm", travelled, scales))
    if data.has_time:
        elapsed = data.time_s - data.time_s[last]
        span = float(np.ptp(data.time_s))
        if span > 0:
            candidates.append(("time", "time_scale_s", elapsed, span * np.geomspace(0.002, 0.2, 13)))
    for over, key, x, scales in candidates:
        best: dict[str, Any] | None = None
        for scale in scales:
            gain, coef = fit.gain(sign, sign * np.exp(-x / scale))  # with a change of the loop's width
            if best is None or gain > best["gain"]:
                best = {"shape": f"transition_after_reversal_in_{over}", "gain": gain, key: float(scale),
                        "amplitude_arcsec": float(coef[1]), "half_width_change_arcsec": float(coef[0])}
        if best is not None:
            out.append(best)
    return out


def _lagged_response(data: DesignData, fit: _ShapeFit) -> dict[str, Any] | None:
    """A part of the twist that follows the torque through a first-order lag (creep, viscoelasticity): the
    torque filtered with time constant τ, at the best of a few τ, fitted together with the torque itself."""
    if not data.has_time or len(data.time_s) < 3:
        return None
    dt = np.diff(data.time_s)
    step_s = float(np.median(dt[dt > 0])) if np.any(dt > 0) else 0.0
    span = float(np.ptp(data.time_s))
    if not step_s > 0 or not span > 0:
        return None
    torque = data.torque_nm - data.torque_nm.mean()
    best: dict[str, Any] | None = None
    for tau in span * np.geomspace(0.002, 0.2, 13):
        alpha = 1.0 - math.exp(-step_s / tau)
        lagged = lfilter([alpha], [1.0, alpha - 1.0], torque, zi=[torque[0] * (1.0 - alpha)])[0]
        gain, coef = fit.gain(torque, lagged)
        if best is None or gain > best["gain"]:
            best = {"shape": "lagged_response", "gain": gain, "time_constant_s": float(tau),
                    "arcsec_per_nm": float(coef[1])}
    return best


def _shapes(data: DesignData, before: np.ndarray, after: np.ndarray, noise: float) -> list[dict[str, Any]]:
    """Candidate shapes of what remains, each with the variance it removes from ``after`` (″², key ``gain``)."""
    n = len(after)
    fit = _ShapeFit(before, before - after)
    out: list[dict[str, Any]] = []
    t = data.time_s if data.has_time else np.arange(n, dtype=float)
    at = "at_time_s" if data.has_time else "at_sample"
    steps = _steps(t, after, noise, data.direction)
    if steps:
        gain, coef = fit.gain(*[(t >= cut).astype(float) for cut in steps])
        out.append({"shape": "step", "gain": gain, at: steps[0], "height_arcsec": float(coef[0]),
                    **({"at_s_after_start": steps[0] - float(t[0])} if data.has_time else {}),
                    "steps": [{at: cut, "height_arcsec": float(h),
                               **({"at_s_after_start": cut - float(t[0])} if data.has_time else {})}
                              for cut, h in zip(steps, coef, strict=True)]})
    gain, coef = fit.gain(t - t.mean())
    out.append({"shape": "ramp", "gain": gain,
                f"slope_arcsec_per_{'s' if data.has_time else 'sample'}": float(coef[0])})
    if data.has_time:  # a compliance that changes over the test (a stiffness drifting with temperature)
        gain, coef = fit.gain(data.torque_nm * (t - t.mean()))
        out.append({"shape": "stiffness_change_in_time", "gain": gain,
                    "arcsec_per_nm_per_s": float(coef[0])})
    gain, coef = fit.gain(data.direction.astype(float))
    out.append({"shape": "loop_width_change", "gain": gain, "half_width_change_arcsec": float(coef[0])})
    if data.has_time:
        rate = angle_rate(data)
        if np.ptp(rate) > 0:
            gain, coef = fit.gain(rate)
            out.append({"shape": "rate_dependent", "gain": gain, "lag_s": float(-coef[0])})
    out.extend(_after_reversal(data, fit))
    lagged = _lagged_response(data, fit)
    if lagged is not None:
        out.append(lagged)
    theta = data.sim_angle_arcsec
    best_sat: dict[str, Any] | None = None
    for end, qs in (("upper", np.linspace(0.5, 0.97, 24)), ("lower", np.linspace(0.03, 0.5, 24))):
        for q in qs:
            knee = float(np.quantile(theta, q))
            hinge = np.maximum(theta - knee, 0.0) if end == "upper" else np.minimum(theta - knee, 0.0)
            if not np.any(hinge):
                continue
            gain, coef = fit.gain(hinge)
            if best_sat is None or gain > best_sat["gain"]:
                best_sat = {"shape": "saturation", "gain": gain, "end": end, "from_angle_arcsec": knee,
                            "slope_arcsec_per_arcsec": float(coef[0])}
    if best_sat is not None:
        out.append(best_sat)
    r = after - after.mean()
    span = float(np.ptp(theta))
    if span > 0:
        periods = np.geomspace(max(2.0, data.signal_period_arcsec / 8), max(span / 2, 4.0), 120)
        amp = periodogram(theta, r, periods)
        i = int(np.argmax(amp))
        out.append({"shape": "periodic_in_angle", "gain": float(amp[i] ** 2 / 2),
                    "period_arcsec": float(periods[i]), "amplitude_arcsec": float(amp[i])})
    if data.has_time and np.ptp(t) > 0:
        lines = time_lines(t, r)
        if lines:  # evenly sampled: the FFT's lines, every one of them
            period, amplitude, _ = lines[0]
            out.append({"shape": "periodic_in_time", "gain": float(amplitude ** 2 / 2), "period_s": period,
                        "amplitude_arcsec": amplitude,
                        "lines": [{"period_s": p, "amplitude_arcsec": a} for p, a, _ in lines]})
        else:
            dt = np.diff(t)
            step = float(np.median(dt[dt > 0])) if np.any(dt > 0) else 1.0
            periods = np.geomspace(8 * step, float(np.ptp(t)) / 2, 100)
            amp = periodogram(t, r, periods)
            i = int(np.argmax(amp))
            out.append({"shape": "periodic_in_time", "gain": float(amp[i] ** 2 / 2), "period_s": float(periods[i]),
                        "amplitude_arcsec": float(amp[i])})
    spikes, local = isolated_spikes(r, noise, data.direction)
    if spikes.any():
        out.append({"shape": "spikes", "gain": float(np.sum(local[spikes] ** 2) / n), "count": int(spikes.sum()),
                    "largest_arcsec": float(np.max(np.abs(local[spikes])))})
    return out


def _spans(data: DesignData, r: np.ndarray, noise: float, limit: int = 3) -> list[dict[str, Any]]:
    """The time spans whose mean residual stands out (≥ 4 standard errors and ≥ ¼ of the noise)."""
    n = len(r)
    t = data.time_s if data.has_time else np.arange(n, dtype=float)
    index = equal_count_bins(t, _time_bins(n))
    counts = np.bincount(index).astype(float)
    means = np.bincount(index, weights=r) / np.maximum(counts, 1)
    flagged = (np.abs(means) >= 4 * noise / np.sqrt(np.maximum(counts, 1))) & (np.abs(means) >= 0.25 * noise)
    runs: list[tuple[int, int]] = []
    b = 0
    while b < len(flagged):
        if flagged[b]:
            e = b
            while e + 1 < len(flagged) and (flagged[e + 1] or (e + 2 < len(flagged) and flagged[e + 2])):
                e += 1
            runs.append((b, e))
            b = e + 1
        else:
            b += 1
    spans = []
    for b, e in runs:
        rows = (index >= b) & (index <= e)
        weight = float(np.sum(np.abs(r[rows])))
        spans.append((weight, {
            ("from_time_s" if data.has_time else "from_sample"): float(t[rows].min()),
            ("to_time_s" if data.has_time else "to_sample"): float(t[rows].max()),
            "from_s_after_start": float(t[rows].min() - t[0]) if data.has_time else None,
            "to_s_after_start": float(t[rows].max() - t[0]) if data.has_time else None,
            "torque_range_nm": [float(data.torque_nm[rows].min()), float(data.torque_nm[rows].max())],
            "loading_share": float(np.mean(data.direction[rows] > 0)),
            "mean_arcsec": float(r[rows].mean()),
            "peak_bin_mean_arcsec": float(means[b:e + 1][np.argmax(np.abs(means[b:e + 1]))]),
            "share_of_samples": float(rows.mean()),
        }))
    spans.sort(key=lambda s: -s[0])
    return [s for _, s in spans[:limit]]


def _direction_words(loading_share: float) -> str:
    if loading_share >= 0.8:
        return "while loading"
    if loading_share <= 0.2:
        return "while unloading"
    return "in both load directions"


def describe_remainder(data: DesignData, before: np.ndarray, after: np.ndarray, noise: float) -> dict[str, Any]:
    """The ``unexplained`` block: where, how large and what shape the structure left in ``after`` is."""
    r = np.asarray(after, dtype=float) - float(np.mean(after))
    excess = max(0.0, float(np.mean(r**2)) - noise**2) if noise > 0 else float(np.mean(r**2))
    shapes = _shapes(data, np.asarray(before, dtype=float), np.asarray(after, dtype=float), noise)
    for s in shapes:
        s["share_of_remainder"] = float(min(1.0, s["gain"] / excess)) if excess > 0 else 0.0
        del s["gain"]
    shapes.sort(key=lambda s: -s["share_of_remainder"])
    best = shapes[0] if shapes and shapes[0]["share_of_remainder"] >= SHAPE_MIN_FRACTION else None
    spans = _spans(data, r, noise)
    windows = torque_windows(data, r, noise)
    up = data.direction > 0
    loading_rms = float(np.sqrt(np.mean(r[up] ** 2))) if up.any() else 0.0
    unloading_rms = float(np.sqrt(np.mean(r[~up] ** 2))) if (~up).any() else 0.0
    return {
        "structured_rms_arcsec": math.sqrt(excess),
        "max_abs_arcsec": float(np.max(np.abs(r))) if len(r) else 0.0,
        "shape": best["shape"] if best else "irregular",
        "shape_detail": best,
        "shapes_considered": shapes,
        "spans": spans,
        "torque_windows": windows,
        "rms_loading_arcsec": loading_rms,
        "rms_unloading_arcsec": unloading_rms,
        "against_rate": _rate_dependence(data, r),
        "summary": _summary(best, spans, math.sqrt(excess), noise, data.has_time),
    }


def _rate_dependence(data: DesignData, r: np.ndarray) -> float | None:
    """Correlation of |residual| with |angle rate| (a rate-dependent remainder: creep, damping), or None."""
    if not data.has_time:
        return None
    rate = np.abs(angle_rate(data))
    if np.ptp(rate) <= 0:
        return None
    return float(np.corrcoef(rate, np.abs(r))[0, 1])


def _summary(best: dict[str, Any] | None, spans: list[dict[str, Any]], structured: float, noise: float,
             has_time: bool) -> str:
    size = f"{structured:.2g}″ RMS beyond the noise ({noise:.2g}″)"
    if best is None:
        shape = ("no simple shape (step, ramp, saturation, loop width or shape, rate, lag, periodicity, spikes) "
                 "describes it")
    else:
        share = f"{best['share_of_remainder']:.0%} of it"
        shape = {
            "step": lambda b: f"a step of {b['height_arcsec']:+.3g}″ "
                              + (f"{b['at_s_after_start']:.4g} s after the start" if "at_time_s" in b
                                 else f"at sample {b['at_sample']:.0f}"),
            "ramp": lambda b: "a ramp in time",
            "stiffness_change_in_time": lambda b: (
                f"a compliance changing over the test by {b['arcsec_per_nm_per_s']:+.2g}″/N·m per s (a stiffness "
                "drifting, e.g. with temperature)"),
            "loop_width_change": lambda b: f"a change of the loop's half-width by {b['half_width_change_arcsec']:+.3g}″",
            "saturation": lambda b: f"a saturation at the {b['end']} end of the angle from {b['from_angle_arcsec']:.4g}″",
            "periodic_in_angle": lambda b: f"a periodicity of {b['period_arcsec']:.4g}″ in angle "
                                           f"({b['amplitude_arcsec']:.2g}″)",
            "periodic_in_time": lambda b: f"a periodicity of {b['period_s']:.4g} s in time ({b['amplitude_arcsec']:.2g}″)",
            "spikes": lambda b: f"{b['count']} spikes up to {b['largest_arcsec']:.3g}″",
            "rate_dependent": lambda b: f"a dependence on the loading rate (as a lag of {b['lag_s']:.2g} s)",
            "transition_after_reversal_in_torque": lambda b: (
                f"a transition of {b['amplitude_arcsec']:+.2g}″ after each load reversal, decaying over "
                f"{b['torque_scale_nm']:.3g} N·m (a friction loop of another shape or width)"),
            "lagged_response": lambda b: (
                f"a twist that follows the torque with a lag of {b['time_constant_s']:.3g} s "
                f"({b['arcsec_per_nm']:.2g}″/N·m: creep or viscoelasticity)"),
            "transition_after_reversal_in_time": lambda b: (
                f"a transition of {b['amplitude_arcsec']:+.2g}″ after each load reversal, decaying over "
                f"{b['time_scale_s']:.3g} s (creep or relaxation)"),
        }[best["shape"]](best) + f" ({share})"
    where = ""
    if spans:
        s = spans[0]
        lo, hi = s["torque_range_nm"]
        if has_time:
            where = (f"; most visible {s['from_s_after_start']:.4g}…{s['to_s_after_start']:.4g} s after the start, "
                     f"torque {lo:.4g}…{hi:.4g} N·m, {_direction_words(s['loading_share'])}")
        else:
            where = f"; most visible at torque {lo:.4g}…{hi:.4g} N·m, {_direction_words(s['loading_share'])}"
    return f"{size}: {shape}{where}"


@dataclass(frozen=True)
class Verdict:
    verdict: str
    noise_floor_arcsec: float
    before: Structure
    after: Structure
    removed_share: float  # share of the structured variance the named effects removed (0…1)
    unexplained: dict[str, Any] | None
    not_identified: dict[str, str] = field(default_factory=dict)  # name → why it may stand in for another shape

    @property
    def provisional(self) -> bool:
        """Names found here are provisional: structure remained that they do not explain."""
        return self.verdict in ("partially_explained", "unexplained")

    def to_dict(self) -> dict[str, Any]:
        return {"verdict": self.verdict, "noise_floor_arcsec": self.noise_floor_arcsec,
                "names_provisional": self.provisional, "structure_removed_share": self.removed_share,
                "structure_before": self.before.to_dict(), "structure_after": self.after.to_dict(),
                "names_not_identified": self.not_identified, "unexplained": self.unexplained,
                "words": self.words(), "notices": notices_of(self.notices())}

    def notices(self) -> list[Notice]:
        """The verdict in sentences, each with its code (the pages translate them): what the verdict means, each
        name that is not identified and why, and what remains."""
        if self.verdict == "consistent":
            said = [Notice("disc_consistent", "Measurement and simulation agree to within the noise: nothing to add.")]
        elif self.verdict == "explained":
            said = [Notice("disc_explained", "The named effects explain the discrepancy: what remains is noise.")]
        elif self.verdict == "partially_explained":
            said = [Notice("disc_partially_explained", "The named effects explain {share} of the discrepancy; "
                           "structure remains that the catalogue does not describe, so the names are provisional.",
                           share=f"{self.removed_share:.0%}")]
        elif self.removed_share > 0:
            said = [Notice("disc_unexplained_provisional", "The discrepancy is not explained by the catalogue (the "
                           "names found remove little of it and are provisional).")]
        else:
            said = [Notice("disc_unexplained", "The discrepancy is not explained by the catalogue.")]
        said += [Notice("disc_not_identified", "{name} takes up part of it, but is not identified: {why}.",
                        name=name, why=why) for name, why in self.not_identified.items()]
        if self.unexplained is not None:
            said.append(Notice("disc_remains", "What remains: {summary}.", summary=self.unexplained["summary"]))
        return said

    def words(self) -> str:
        return " ".join(self.notices())


def judge(data: DesignData, before: np.ndarray, after: np.ndarray, *, any_named: bool,
          not_identified: dict[str, str] | None = None, after_identified: np.ndarray | None = None) -> Verdict:
    """The verdict on a workflow's residuals before and after adding the named effects.

    ``not_identified`` names fitted terms that may stand in for a shape outside the catalogue (their reason),
    and ``after_identified`` is the residual after the other names alone. Such names never make the
    discrepancy ``explained``: the structure is judged on what the identified names leave."""
    noise = noise_floor_arcsec(before, data.time_s if data.has_time else None)
    not_identified = dict(not_identified or {})
    if not_identified and after_identified is not None:
        after = after_identified
    s_before = structure(data, before, noise)
    s_after = structure(data, after, noise)
    removed = (1.0 - s_after.excess_variance / s_before.excess_variance) if s_before.excess_variance > 0 else 0.0
    removed = float(min(1.0, max(0.0, removed)))
    if not s_before.present:
        verdict = "consistent" if not any_named else ("explained" if not s_after.present else "partially_explained")
    elif not any_named:
        verdict = "unexplained"
    elif not s_after.present:
        verdict = "explained"
    else:
        verdict = "partially_explained" if removed >= SHARE_FOR_PARTIAL else "unexplained"
    if verdict == "explained" and not_identified:
        verdict = "partially_explained"
    remainder = describe_remainder(data, before, after, noise) if s_after.present else None
    return Verdict(verdict, noise, s_before, s_after, removed, remainder, not_identified)

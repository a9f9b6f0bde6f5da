"""Plausibility of a hysteresis record: what must not pass silently (warnings of ``evaluate``).

Pure functions on the record and its segmentation; each returns its finding, and ``evaluate`` words the warning:
- an angle span that suggests the angle column is in degrees or radians, not arcsec;
- turning points of reduced amplitude (the loops around them are not evaluated);
- loop closure and drift: the angle at the turning points of one sign, corrected for the torque reached, should
  not move with time; a drift biases the backlash (the branches cross zero torque at different times) by
  rate × (t_B↓(0) − t_B↑(0)); the rate comes with its standard uncertainty, and ``evaluate`` corrects a significant
  drift;
- sampling too coarse for the loop: the torque between the samples bracketing the evaluation levels.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tcms_daq.analysis.segmentation import Branch, Loop, TurningPoint
from tcms_daq.units import ARCSEC_PER_DEG, ARCSEC_PER_RAD

MIN_SPAN_ARCSEC = 1.0  # a loop spanning less angle than this is below any angle encoder's accuracy
TIP_BAND_FRACTION = 0.005  # samples within 0.5 % of the scale of a turning point's torque belong to the tip
DRIFT_BIAS_WARNING_ARCSEC = 0.1  # warn when drift moves the backlash by more than this …
DRIFT_BIAS_WARNING_FRACTION = 0.01  # … and by more than 1 % of it
COARSE_FRACTION = 0.5  # warn when the torque between samples exceeds half the lost-motion level


def unit_hint(span_arcsec: float) -> str:
    """How large the span would be if the column were in degrees or radians."""
    return (f"in degrees it would be {span_arcsec * ARCSEC_PER_DEG:.4g}″, in radians "
            f"{span_arcsec * ARCSEC_PER_RAD:.4g}″")


def implausible_span(angle_arcsec: np.ndarray) -> float | None:
    """The angle span (arcsec) when it is too small to be arcsec, else None."""
    span = float(np.ptp(angle_arcsec))
    return span if span < MIN_SPAN_ARCSEC else None


def reduced_turning_points(tips: list[TurningPoint], fraction: float) -> tuple[list[TurningPoint], float]:
    """Turning points below ``fraction`` of the typical |torque| of all turning points, and that typical value."""
    if not tips:
        return [], 0.0
    typical = float(np.median([abs(t.torque_nm) for t in tips]))
    return [t for t in tips if abs(t.torque_nm) < fraction * typical], typical


@dataclass(frozen=True)
class Drift:
    """Angle drift estimated from the turning points: rate (″/s), the closure of the record (the angle change at
    the same turning-point torque from the first to the last turning point of one sign, ″, over ``span_s``)."""

    rate_arcsec_per_s: float
    closure_arcsec: float
    span_s: float
    tips: int
    rate_u_arcsec_per_s: float  # standard uncertainty of the rate from the fit's residuals (NaN: no redundancy)


def _tip_means(time_s: np.ndarray, torque_nm: np.ndarray, angle_arcsec: np.ndarray, torque_smooth_nm: np.ndarray,
               tip: TurningPoint, band_nm: float) -> tuple[float, float, float]:
    """Mean time, torque and angle of the contiguous samples around a turning point within ``band_nm`` of it."""
    near = np.abs(torque_smooth_nm - tip.torque_nm) <= band_nm
    lo = hi = tip.index
    while lo > 0 and near[lo - 1]:
        lo -= 1
    while hi + 1 < near.size and near[hi + 1]:
        hi += 1
    sl = slice(lo, hi + 1)
    return float(np.mean(time_s[sl])), float(np.mean(torque_nm[sl])), float(np.mean(angle_arcsec[sl]))


def drift_from_turning_points(time_s: np.ndarray, torque_nm: np.ndarray, angle_arcsec: np.ndarray,
                              torque_smooth_nm: np.ndarray, tips: list[TurningPoint], scale_nm: float,
                              compliance_arcsec_per_nm: float) -> Drift | None:
    """Drift rate by least squares over the turning points: angle − compliance·torque = offset(sign) + rate·t.

    Needs two turning points of one sign (one full loop); None otherwise.
    """
    if len(tips) < 3:
        return None
    band = TIP_BAND_FRACTION * scale_nm
    rows = [(*_tip_means(time_s, torque_nm, angle_arcsec, torque_smooth_nm, tp, band), tp.sign) for tp in tips]
    t = np.array([r[0] for r in rows])
    corrected = np.array([r[2] - compliance_arcsec_per_nm * r[1] for r in rows])
    sign = np.array([r[3] for r in rows])
    design = np.column_stack([t - t[0], sign > 0, sign < 0]).astype(float)
    coef = np.linalg.lstsq(design, corrected, rcond=None)[0]
    rate = float(coef[0])
    span = float(t[-1] - t[0])
    dof = len(rows) - design.shape[1]
    if dof > 0:
        residual = corrected - design @ coef
        cov = float(residual @ residual) / dof * np.linalg.pinv(design.T @ design)
        rate_u = float(np.sqrt(max(cov[0, 0], 0.0)))
    else:
        rate_u = float("nan")
    return Drift(rate, rate * span, span, len(rows), rate_u)


def zero_crossing_time_s(time_s: np.ndarray, torque_smooth_nm: np.ndarray, branch: Branch) -> float:
    """The time (s) a branch's smoothed torque passes 0 N·m."""
    return float(np.interp(0.0, branch.progress_nm(torque_smooth_nm), time_s[branch.slice]))


def backlash_drift_bias_arcsec(time_s: np.ndarray, torque_smooth_nm: np.ndarray, loop: Loop,
                               rate_arcsec_per_s: float) -> float:
    """What a drift adds to this loop's backlash |θ_B↓(0) − θ_B↑(0)| (″): rate × (t_B↓(0) − t_B↑(0)), with the
    sign that widens the loop (the B↓ branch lies above the B↑ branch at zero torque)."""
    dt = zero_crossing_time_s(time_s, torque_smooth_nm, loop.down) - zero_crossing_time_s(time_s, torque_smooth_nm,
                                                                                         loop.up)
    return rate_arcsec_per_s * dt


def coarsest_sampling_nm(torque_smooth_nm: np.ndarray, branches: list[Branch], levels_nm: np.ndarray) -> float:
    """The largest torque step (N·m) between the two samples that bracket an evaluation level on any branch."""
    worst = 0.0
    for branch in branches:
        progress = branch.progress_nm(torque_smooth_nm)
        target = branch.direction * levels_nm
        inside = (target > progress[0]) & (target <= progress[-1])
        if not inside.any():
            continue
        first = np.searchsorted(progress, target[inside], side="left")
        first = np.clip(first, 1, progress.size - 1)
        worst = max(worst, float(np.max(progress[first] - progress[first - 1])))
    return worst

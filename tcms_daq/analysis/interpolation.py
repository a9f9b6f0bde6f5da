"""The angle on one hysteresis branch at given torque levels.

For each level the first sample where the branch's (smoothed, running-extreme) torque reaches the level is
found; a local least-squares line θ = a + b·T (a parabola from MIN_SAMPLES_QUADRATIC samples on) is fitted
to the ``window`` samples centred there (measured torque as regressor) and evaluated at the level. With
``window = 2`` this is exact linear interpolation between the two bracketing samples, which is what
noiseless data need; noisy data get a longer window (see ``fit_window``). Vectorised over the levels.
"""

from __future__ import annotations

import math

import numpy as np

TARGET_STD_ARCSEC = 0.025  # aim for this std of a single interpolated angle
MAX_SPAN_FRACTION = 0.01  # but never let a window span more than 1 % of the test torque
MIN_SAMPLES_QUADRATIC = 8  # windows this long fit a parabola (no curvature bias in the lost-motion zone)
QUADRATIC_DEGREE = 2


def fit_window(
    angle_noise_arcsec: float,
    torque_noise_nm: float,
    compliance_arcsec_per_nm: float,
    samples_per_nm: float,
    test_torque_nm: float,
) -> int:
    """Number of samples in a local fit: 2 (exact interpolation) for clean data, more for noisy data."""
    effective = math.hypot(angle_noise_arcsec, compliance_arcsec_per_nm * torque_noise_nm)
    wanted = math.ceil((effective / TARGET_STD_ARCSEC) ** 2)
    cap = math.floor(MAX_SPAN_FRACTION * test_torque_nm * samples_per_nm)
    return int(max(2, min(wanted, cap)))


def angle_at_torque(
    torque_nm: np.ndarray,
    angle_arcsec: np.ndarray,
    torque_smooth_nm: np.ndarray,
    direction: int,
    levels_nm: np.ndarray,
    window: int,
) -> np.ndarray:
    """θ (arcsec) of one branch at each torque level (N·m); NaN where the branch does not reach the level.

    ``torque_nm``/``angle_arcsec``/``torque_smooth_nm`` are the branch's samples in time order;
    ``direction`` is +1 for a B↑ (rising torque) branch, −1 for B↓.
    """
    levels = np.atleast_1d(np.asarray(levels_nm, dtype=float))
    n_samples = torque_nm.size
    progress = np.maximum.accumulate(direction * torque_smooth_nm)
    target = direction * levels
    reached = (target >= progress[0]) & (target <= progress[-1])
    first = np.searchsorted(progress, target, side="left")
    n = int(min(max(window, 2), n_samples))
    start = np.clip(first - n // 2, 0, n_samples - n)
    idx = start[:, None] + np.arange(n)[None, :]
    t = torque_nm[idx]
    a = angle_arcsec[idx]
    # Regress on x = T − level, scaled to O(1): the intercept is the angle at the level.
    x = t - levels[:, None]
    scale = np.maximum(np.abs(x).max(axis=1, keepdims=True), 1e-12)
    x = x / scale
    degree = QUADRATIC_DEGREE if n >= MIN_SAMPLES_QUADRATIC else 1
    design = np.stack([x**k for k in range(degree + 1)], axis=2)  # (levels, n, degree+1)
    normal = np.einsum("lik,lij->lkj", design, design)
    rhs = np.einsum("lik,li->lk", design, a)
    # Ill-conditioned windows (all samples at one torque, e.g. a dwell) fall back to their mean angle.
    cond_ok = np.linalg.cond(normal) < 1e10
    out = a.mean(axis=1)
    if cond_ok.any():
        out[cond_ok] = np.linalg.solve(normal[cond_ok], rhs[cond_ok][..., None])[:, 0, 0]
    out[~reached] = np.nan
    return out

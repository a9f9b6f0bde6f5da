"""The angle on one hysteresis branch at given torque levels.

For each level the first sample where the branch's (smoothed, running-extreme) torque reaches the level is
found. Torque and angle of the ``window`` samples centred there are fitted by least-squares polynomials in
time (lines, parabolas from MIN_SAMPLES_QUADRATIC samples on); the angle is read at the time where the torque
polynomial equals the level. If the angle is locally linear in torque the result is exact whatever the torque
profile does inside the window (the LS projection is linear), and noisy torque causes no errors-in-variables
bias. With ``window = 2`` this is exact linear interpolation between the two bracketing samples, which is
what noiseless data need; noisy data get a longer window (see ``fit_window``). Vectorised over the levels.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

TARGET_STD_ARCSEC = 0.025  # aim for this std of a single interpolated angle
MAX_SPAN_FRACTION = 0.02  # but a window never spans more than 2 % of the test torque
MAX_WINDOW = 2000  # samples; beyond this more averaging gains nothing measurable
MIN_SAMPLES_QUADRATIC = 5  # windows this long fit a parabola (no curvature bias in the lost-motion zone)
QUADRATIC_DEGREE = 2


def fit_window(angle_noise_arcsec: float, torque_noise_nm: float, compliance_arcsec_per_nm: float) -> int:
    """Samples wanted in a local fit: 2 (exact interpolation) for clean data, more for noisy data.

    The effective angle noise at a fixed torque is √(σ_θ² + (c·σ_T)²) with c the compliance (″/N·m); the window
    averages it down to TARGET_STD_ARCSEC. ``angle_at_torque`` also limits the torque span of the window.
    """
    effective = math.hypot(angle_noise_arcsec, compliance_arcsec_per_nm * torque_noise_nm)
    wanted = math.ceil((effective / TARGET_STD_ARCSEC) ** 2)
    return int(max(2, min(wanted, MAX_WINDOW)))


def _products_summed(weighted: np.ndarray, other: np.ndarray) -> np.ndarray:
    """``Σ_i weighted[l, i, k] · other[l, i, c]`` as (levels, k, c): ``einsum("lik,lic->lkc")`` bit for bit (the
    products summed in sample order from the first) at a third of its CPU for the fits' small k and c, where
    einsum's inner loop is only k long. The samples are laid outermost and the levels innermost, so every
    product is one long multiply and the sum over the samples a sequential reduction over the first axis."""
    by_sample_w = np.ascontiguousarray(weighted.transpose(1, 2, 0))  # (n, k, levels)
    by_sample_o = np.ascontiguousarray(other.transpose(1, 2, 0))  # (n, c, levels)
    summed: np.ndarray = (by_sample_w[:, :, None, :] * by_sample_o[:, None, :, :]).sum(axis=0)
    return summed.transpose(2, 0, 1)


def _solve(u: np.ndarray, weight: np.ndarray, values: np.ndarray, degree: int) -> np.ndarray:
    """Weighted LS polynomial coefficients (levels, degree+1, columns) of ``values`` (levels, n, columns) in u."""
    design = np.stack([u**k for k in range(degree + 1)], axis=2)  # (levels, n, degree+1)
    weighted = design * weight[:, :, None]
    normal = _products_summed(weighted, design)
    rhs = _products_summed(weighted, values)
    return np.linalg.solve(normal, rhs)


@dataclass(frozen=True)
class _Windows:
    """The samples each level's local fit uses: ``idx`` (levels, n) sample indices, ``weight`` which of them are
    used, ``first`` the first sample at or past the level, ``reached`` whether the branch reaches it."""

    levels: np.ndarray
    idx: np.ndarray
    weight: np.ndarray
    first: np.ndarray
    reached: np.ndarray

    @property
    def count(self) -> np.ndarray:
        return np.asarray(self.weight.sum(axis=1))

    @property
    def quadratic(self) -> np.ndarray:
        return np.asarray(self.count >= MIN_SAMPLES_QUADRATIC)


def _windows(torque_nm: np.ndarray, torque_smooth_nm: np.ndarray, direction: int, levels_nm: np.ndarray,
             window: int, max_span_nm: float) -> _Windows:
    levels = np.atleast_1d(np.asarray(levels_nm, dtype=float))
    n_samples = torque_nm.size
    progress = np.maximum.accumulate(direction * torque_smooth_nm)
    target = direction * levels
    reached = (target >= progress[0]) & (target <= progress[-1])
    first = np.clip(np.searchsorted(progress, target, side="left"), 1, n_samples - 1)
    n = int(min(max(window, 2), n_samples))
    start = np.clip(first - n // 2, 0, n_samples - n)
    idx = start[:, None] + np.arange(n)[None, :]
    weight = np.abs(torque_nm[idx] - levels[:, None]) <= 0.5 * max_span_nm
    weight |= (idx == first[:, None]) | (idx == first[:, None] - 1)
    # Only the samples within the span are fitted: each level's used samples packed to the left in their order (the
    # fits may cut each group of levels to its own widest), the columns no level uses dropped. The fits are the
    # same sums without their zero terms; a long window (noisy data) that the span cuts short then costs what its
    # used samples cost.
    packed = np.argsort(~weight, axis=1, kind="stable")[:, : int(weight.sum(axis=1).max())]
    idx, weight = np.take_along_axis(idx, packed, axis=1), np.take_along_axis(weight, packed, axis=1)
    return _Windows(levels, idx, weight, first, reached)


def _by_width(count: np.ndarray, rows: np.ndarray) -> list[np.ndarray]:
    """``rows`` (a mask over the levels) split in two by their used sample count: those up to twice the median and
    the rest (a level in a hold uses its whole window, a level on the move a few samples), so that each part is
    fitted over its own widest window, not every level over the widest of all."""
    if not rows.any():
        return []
    narrow = rows & (count <= 2 * np.median(count[rows]))
    return [part for part in (narrow, rows & ~narrow) if part.any()]


def angle_at_torque(
    time_s: np.ndarray,
    torque_nm: np.ndarray,
    angle_arcsec: np.ndarray,
    torque_smooth_nm: np.ndarray,
    direction: int,
    levels_nm: np.ndarray,
    window: int,
    max_span_nm: float = math.inf,
) -> np.ndarray:
    """θ (arcsec) of one branch at each torque level (N·m); NaN where the branch does not reach the level.

    ``time_s``/``torque_nm``/``angle_arcsec``/``torque_smooth_nm`` are the branch's samples in time order;
    ``direction`` is +1 for a B↑ (rising torque) branch, −1 for B↓. At most ``window`` samples are used per
    level, only those whose torque lies within ±max_span_nm/2 of the level, and always the two
    samples bracketing it.
    """
    w = _windows(torque_nm, torque_smooth_nm, direction, levels_nm, window, max_span_nm)
    levels, idx, weight, reached = w.levels, w.idx, w.weight, w.reached
    # Time, exact, is the regressor: fitting torque and angle against it avoids the errors-in-variables bias of
    # regressing angle on noisy torque. u spans [−1, 1] over the samples used.
    t = time_s[idx]
    t_lo = np.where(weight, t, np.inf).min(axis=1, keepdims=True)
    t_hi = np.where(weight, t, -np.inf).max(axis=1, keepdims=True)
    u = np.clip(2.0 * (t - t_lo) / (t_hi - t_lo) - 1.0, -1.0, 1.0)
    values = np.stack([torque_nm[idx], angle_arcsec[idx]], axis=2)
    coef = np.zeros((levels.size, QUADRATIC_DEGREE + 1, 2))
    quadratic, count = w.quadratic, w.count
    for degree, rows in ((QUADRATIC_DEGREE, quadratic), (1, ~quadratic)):
        for part in _by_width(count, rows):
            m = int(count[part].max())  # the used samples are packed to the left (``_windows``)
            coef[part, : degree + 1] = _solve(u[part, :m], weight[part, :m].astype(float), values[part, :m], degree)
    c = coef[:, :, 0]  # torque polynomial in u
    p = coef[:, :, 1]  # angle polynomial in u
    # Solve torque(u*) = level for the root inside the window (stable quadratic formula; linear if c2 = 0).
    d = c[:, 0] - levels
    c1, c2 = c[:, 1], c[:, 2]
    disc = c1 * c1 - 4.0 * c2 * d
    with np.errstate(divide="ignore", invalid="ignore"):
        u_star = np.where(disc >= 0.0, -2.0 * d / (c1 + np.copysign(np.sqrt(np.maximum(disc, 0.0)), c1)), -d / c1)
    # A flat window (dwell at one torque) has no defined crossing: any time in it gives the same angle.
    u_star = np.clip(np.nan_to_num(u_star, nan=0.0, posinf=1.0, neginf=-1.0), -1.0, 1.0)
    out = p[:, 0] + p[:, 1] * u_star + p[:, 2] * u_star**2
    out[~reached] = np.nan
    return np.asarray(out, dtype=float)


def spacing_bound_arcsec(
    torque_nm: np.ndarray,
    angle_arcsec: np.ndarray,
    torque_smooth_nm: np.ndarray,
    direction: int,
    levels_nm: np.ndarray,
    window: int,
    max_span_nm: float = math.inf,
) -> np.ndarray:
    """Half-width (arcsec) of the error ``angle_at_torque`` can make at each level from the local sample spacing;
    0 where the branch does not reach the level.

    A straight line through samples spanning h of torque misses a branch of curvature θ'' = d²θ/dT² by at most
    |θ''|·h²/8 between them (the largest gap between a parabola and its chord); with two samples that is linear
    interpolation, Δ the torque step between them. A level read from a parabola has no curvature error (its
    third-order error is not bounded here). θ'' is the curvature of a least-squares parabola θ(T) over the branch's
    samples within ±max(2h, max_span_nm) of the level (the smoothed torque: the bound needs the shape, not an
    unbiased slope).
    """
    w = _windows(torque_nm, torque_smooth_nm, direction, levels_nm, window, max_span_nm)
    out = np.zeros(w.levels.size)
    for k in np.flatnonzero(w.reached & ~w.quadratic):
        used = w.idx[k][w.weight[k]]
        h = float(np.ptp(torque_smooth_nm[used]))
        if h <= 0.0:
            continue
        half = max(2.0 * h, max_span_nm if math.isfinite(max_span_nm) else 2.0 * h)
        near = np.flatnonzero(np.abs(torque_smooth_nm - w.levels[k]) <= half)
        if near.size < 4 or np.ptp(torque_smooth_nm[near]) <= 0.0:
            continue
        x = torque_smooth_nm[near] - w.levels[k]
        curvature = 2.0 * float(np.polyfit(x, angle_arcsec[near], 2)[0])
        out[k] = abs(curvature) * h * h / 8.0
    return out

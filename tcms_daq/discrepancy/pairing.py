"""Pairs as users have them: put a simulation onto the measured rows before comparing (pure numpy).

A simulation a user brings (their own model, an FE or multibody run, the bench model) rarely has the measured
rows. Three cases, tried in order:

* ``same_rows`` — the simulated file has the measured rows (time within ``time_tolerance_s``, torque within a
  millionth of the span): used as it is.
* ``time_grid`` — the simulation ran on its own time grid, possibly offset in time: the offset is estimated
  from the torque traces (cross-correlation, refined to a fraction of a sample) and reported; the simulated
  angle is interpolated onto the measured stamps in the common span. Used when the simulated torque, so
  aligned, agrees with the measured torque to ``TORQUE_AGREEMENT`` of the span (RMS).
* ``equal_torque`` — the simulation was driven by another torque (e.g. the commanded profile, without the
  loader's lag and noise): the loops are compared at equal torque. Each measured load branch (between
  reversals) is matched with the simulated branch of the same direction that overlaps it most in (offset)
  time — or, without time, the branch of the same rank — and the simulated angle is interpolated against
  the simulated torque on that branch at the measured torques.

Rows the simulation does not cover are left out and counted. What cannot be compared is refused with the
reason (``DataFormatError``): no common time span, no branch in common, too few rows left.

A long, densely sampled pair (more than ``MAX_ANALYSIS_ROWS`` rows) is then averaged in blocks of consecutive
samples, never across a load reversal, a time gap or a change of run: the discrepancies the catalogue
describes are smooth at that scale while the noise of each row drops by √(block), so a run sampled at
13.75 kHz carries the same information per analysed row as one at 50 Hz with the same noise density — the
selection's thresholds, set relative to the residual's RMS, would otherwise drown a real 0.5″ effect in
the per-sample noise. The block length is reported.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from tcms_daq.discrepancy.design import branch_starts, load_direction, reversals
from tcms_daq.errors import DataFormatError
from tcms_daq.samples import Samples

TORQUE_AGREEMENT = 1e-3  # RMS torque difference / span below which a time-grid simulation is taken as is
MIN_ROWS = 12
MIN_KEPT_SHARE = 0.5
MAX_ANALYSIS_ROWS = 24_000


@dataclass(frozen=True)
class Pairing:
    mode: str  # "same_rows" | "time_grid" | "equal_torque"
    time_offset_s: float | None  # added to the simulated time stamps (None: not estimated)
    rows_measured: int
    rows_used: int
    torque_rms_difference_nm: float | None  # measured − simulated torque on the used rows (time-aligned)
    block_samples: int = 1  # consecutive samples averaged into one analysed row
    rows_analysed: int | None = None

    def to_dict(self) -> dict[str, Any]:
        return {"mode": self.mode, "time_offset_s": self.time_offset_s, "rows_measured": self.rows_measured,
                "rows_used": self.rows_used, "rows_left_out": self.rows_measured - self.rows_used,
                "torque_rms_difference_nm": self.torque_rms_difference_nm, "block_samples": self.block_samples,
                "rows_analysed": self.rows_analysed if self.rows_analysed is not None else self.rows_used}


def same_rows(measured: Samples, simulated: Samples, *, has_time: bool, time_tolerance_s: float = 1e-6) -> bool:
    """True if ``simulated`` has the measured rows (same count, time and torque within the tolerances)."""
    if len(measured) != len(simulated):
        return False
    if has_time and np.any(np.abs(measured.time_s - simulated.time_s)
                           > time_tolerance_s * max(1.0, float(np.max(np.abs(measured.time_s))))):
        return False
    span = float(np.ptp(measured.torque_nm)) if len(measured) else 0.0
    return bool(np.all(np.abs(measured.torque_nm - simulated.torque_nm) <= max(1e-6 * max(span, 1.0), 1e-9)))


def estimate_time_offset_s(t_measured: np.ndarray, torque_measured: np.ndarray, t_simulated: np.ndarray,
                           torque_simulated: np.ndarray, max_offset_s: float | None = None) -> float:
    """τ (s) such that the measured torque at t best matches the simulated torque at t − τ (cross-correlation
    on a common uniform grid, refined by a parabola through the peak)."""
    dt_m = np.diff(t_measured)
    step = float(np.median(dt_m[dt_m > 0])) if np.any(dt_m > 0) else 0.0
    lo = min(t_measured[0], t_simulated[0])
    hi = max(t_measured[-1], t_simulated[-1])
    if not step > 0 or not hi > lo:
        return 0.0
    n = int(min((hi - lo) / step, 2**20)) + 1
    grid = np.linspace(lo, hi, n)
    step = grid[1] - grid[0] if n > 1 else step
    a = np.interp(grid, t_measured, torque_measured, left=np.nan, right=np.nan)
    b = np.interp(grid, t_simulated, torque_simulated, left=np.nan, right=np.nan)
    a = np.where(np.isfinite(a), a - np.nanmean(a), 0.0)
    b = np.where(np.isfinite(b), b - np.nanmean(b), 0.0)
    size = 1 << int(np.ceil(np.log2(2 * n)))
    xc = np.fft.irfft(np.fft.rfft(a, size) * np.conj(np.fft.rfft(b, size)), size)
    lags = np.concatenate((np.arange(0, n), np.arange(-n + 1, 0)))
    xc = np.concatenate((xc[:n], xc[size - n + 1:]))
    limit = (max_offset_s if max_offset_s is not None else 0.25 * (hi - lo)) / step
    xc = np.where(np.abs(lags) <= limit, xc, -np.inf)
    k = int(np.argmax(xc))
    shift = float(lags[k])
    if 0 < k < len(xc) - 1 and np.isfinite(xc[k - 1]) and np.isfinite(xc[k + 1]):
        denom = xc[k - 1] - 2 * xc[k] + xc[k + 1]
        if denom < 0:
            shift += 0.5 * (xc[k - 1] - xc[k + 1]) / denom
    coarse = shift * step
    refined = _refine_offset(t_measured, torque_measured, t_simulated, torque_simulated, coarse)
    return refined if abs(refined - coarse) <= 2 * step else coarse  # a refinement that wanders is not one


def _refine_offset(t_m: np.ndarray, torque_m: np.ndarray, t_s: np.ndarray, torque_s: np.ndarray, offset_s: float,
                   iterations: int = 4) -> float:
    """Gauss–Newton steps on Σ (T_m(t) − T_s(t − τ))² from ``offset_s`` (the cross-correlation's grid limits
    it to a fraction of a sample; a clock offset left over would look like a time skew)."""
    rate_s = np.gradient(torque_s, t_s)
    for _ in range(iterations):
        at = t_m - offset_s
        inside = (at >= t_s[0]) & (at <= t_s[-1])
        if inside.sum() < MIN_ROWS:
            break
        error = torque_m[inside] - np.interp(at[inside], t_s, torque_s)
        slope = np.interp(at[inside], t_s, rate_s)
        weight = float(slope @ slope)
        if not weight > 0:
            break
        offset_s -= float(error @ slope) / weight
    return offset_s


def _branches(direction: np.ndarray) -> np.ndarray:
    """Branch number of every row (0, 1, … from one load reversal to the next)."""
    labels = np.zeros(len(direction), dtype=int)
    labels[reversals(direction)] = 1
    return np.cumsum(labels)


def _equal_torque(measured: Samples, simulated: Samples, offset_s: float | None) -> np.ndarray:
    """Simulated angle at the measured torques, branch by branch (NaN where no simulated branch covers it)."""
    dir_m, dir_s = load_direction(measured.torque_nm), load_direction(simulated.torque_nm)
    br_m, br_s = _branches(dir_m), _branches(dir_s)
    out = np.full(len(measured), np.nan)
    sim_branches = []
    for k in range(int(br_s.max()) + 1):
        rows = np.flatnonzero(br_s == k)
        if len(rows) >= 2:
            sim_branches.append((k, rows, int(dir_s[rows[0]])))
    for k in range(int(br_m.max()) + 1):
        rows = np.flatnonzero(br_m == k)
        direction = int(dir_m[rows[0]])
        same = [b for b in sim_branches if b[2] == direction]
        if not same:
            continue
        if offset_s is not None:
            t0, t1 = measured.time_s[rows[0]], measured.time_s[rows[-1]]

            def overlap(b, t0=t0, t1=t1):
                s0, s1 = simulated.time_s[b[1][0]] + offset_s, simulated.time_s[b[1][-1]] + offset_s
                return min(t1, s1) - max(t0, s0)

            best = max(same, key=overlap)
            if overlap(best) <= 0:
                continue
        else:
            rank = int(np.sum(dir_m[branch_starts(dir_m)][:k] == direction))
            if rank >= len(same):
                continue
            best = same[rank]
        s_rows = best[1]
        order = np.argsort(simulated.torque_nm[s_rows], kind="stable")
        torque_s = simulated.torque_nm[s_rows][order]
        angle_s = simulated.angle_arcsec[s_rows][order]
        torque_m = measured.torque_nm[rows]
        inside = (torque_m >= torque_s[0]) & (torque_m <= torque_s[-1])
        out[rows[inside]] = np.interp(torque_m[inside], torque_s, angle_s)
    return out


def average_blocks(measured: Samples, simulated: Samples, block: int) -> tuple[Samples, Samples]:
    """Both sides averaged over runs of ``block`` consecutive samples that never cross a load reversal, a time
    gap (> 10 median steps) or a change of ``run_id``; a side's last, shorter block is averaged as it is."""
    n = len(measured)
    bounds = [np.array([0, n])]
    bounds.append(reversals(load_direction(measured.torque_nm)))
    dt = np.diff(measured.time_s)
    if np.any(dt > 0):
        bounds.append(np.flatnonzero(dt > 10 * float(np.median(dt[dt > 0]))) + 1)
    run_id = measured.extra.get("run_id")
    if run_id is not None:
        bounds.append(np.flatnonzero(np.diff(run_id) != 0) + 1)
    edges = np.unique(np.concatenate(bounds))
    starts = np.concatenate([np.arange(a, b, block) for a, b in zip(edges[:-1], edges[1:], strict=True)])
    counts = np.diff(np.append(starts, n)).astype(float)

    def mean(x: np.ndarray) -> np.ndarray:
        return np.add.reduceat(np.asarray(x, dtype=float), starts) / counts

    extra = {"run_id": run_id[starts]} if run_id is not None else {}
    m = Samples(mean(measured.time_s), mean(measured.torque_nm), mean(measured.angle_arcsec), dict(extra))
    s = Samples(m.time_s, m.torque_nm, mean(simulated.angle_arcsec), dict(extra))
    return m, s


def pair(measured: Samples, simulated: Samples, *, has_time: bool = True, time_tolerance_s: float = 1e-6,
         max_rows: int = MAX_ANALYSIS_ROWS) -> tuple[Samples, Samples, Pairing]:
    """(measured rows analysed, simulated on those rows, how) — see the module docstring. Raises
    DataFormatError."""
    m, s, how = _onto_measured_rows(measured, simulated, has_time=has_time, time_tolerance_s=time_tolerance_s)
    if len(m) <= max_rows:
        return m, s, how
    block = int(np.ceil(len(m) / max_rows))
    m, s = average_blocks(m, s, block)
    return m, s, replace(how, block_samples=block, rows_analysed=len(m))


def _onto_measured_rows(measured: Samples, simulated: Samples, *, has_time: bool, time_tolerance_s: float
                        ) -> tuple[Samples, Samples, Pairing]:
    n = len(measured)
    if same_rows(measured, simulated, has_time=has_time, time_tolerance_s=time_tolerance_s):
        return measured, simulated, Pairing("same_rows", None, n, n, None)
    for side, samples in (("measured", measured), ("simulated", simulated)):
        if len(samples) < MIN_ROWS:
            raise DataFormatError(f"{side} has {len(samples)} rows: the discrepancy workflow needs at least "
                                  f"{MIN_ROWS}")
        columns = [("torque_nm", samples.torque_nm), ("angle_arcsec", samples.angle_arcsec)]
        if has_time:
            columns.append(("time_s", samples.time_s))
        for name, values in columns:
            if not np.all(np.isfinite(values)):
                raise DataFormatError(f"{side} {name} is not finite everywhere: the workflow needs finite samples")
        if has_time and np.any(np.diff(samples.time_s) < 0):
            raise DataFormatError(f"{side} time_s goes backwards: rows must be in time order")
    if not np.ptp(simulated.torque_nm) > 0:
        raise DataFormatError("simulated torque_nm is constant: there is no torque–angle curve to compare")
    offset: float | None = None
    torque_difference: float | None = None
    angle = None
    mode = "equal_torque"
    if has_time:
        offset = estimate_time_offset_s(measured.time_s, measured.torque_nm, simulated.time_s, simulated.torque_nm)
        t_sim = simulated.time_s + offset
        covered = (measured.time_s >= t_sim[0]) & (measured.time_s <= t_sim[-1])
        if not covered.any():
            raise DataFormatError(
                f"no common time span: measured {measured.time_s[0]:g}…{measured.time_s[-1]:g} s, simulated "
                f"{simulated.time_s[0]:g}…{simulated.time_s[-1]:g} s even after the best offset {offset:+.4g} s")
        torque_on_rows = np.interp(measured.time_s, t_sim, simulated.torque_nm)
        diff = (measured.torque_nm - torque_on_rows)[covered]
        torque_difference = float(np.sqrt(np.mean(diff**2)))
        span = float(np.ptp(measured.torque_nm))
        if torque_difference <= TORQUE_AGREEMENT * span:
            mode = "time_grid"
            angle = np.where(covered, np.interp(measured.time_s, t_sim, simulated.angle_arcsec), np.nan)
    if angle is None:
        angle = _equal_torque(measured, simulated, offset)
    keep = np.isfinite(angle)
    used = int(keep.sum())
    if used < max(MIN_ROWS, MIN_KEPT_SHARE * n):
        raise DataFormatError(
            f"the simulation covers only {used} of the {n} measured rows ({mode.replace('_', ' ')}): the two runs "
            "do not share enough of their loops to compare")
    extra_m = {k: v[keep] for k, v in measured.extra.items()}
    m = Samples(measured.time_s[keep], measured.torque_nm[keep], measured.angle_arcsec[keep], extra_m)
    s = Samples(m.time_s, m.torque_nm, angle[keep], {k: v for k, v in extra_m.items() if k == "run_id"})
    return m, s, Pairing(mode, offset, n, used, torque_difference)

"""The aligned measured/simulated pair as the discrepancy workflow sees it (pure numpy).

Derived signals every catalogue term is built from: load direction (+1 while the torque increases,
−1 while it decreases, from a hysteresis turning-point detector so noise does not flip it), the local
slope dθ_sim/dT of the simulated curve (for a user's declared effect), the simulated curve's history-free part
(for reading it at T − T0: a torque offset), the groups for blocked cross-validation (runs, else loops between
torque minima, else contiguous blocks) and the time-continuous segments (for re-evaluating the simulation
at t + τ).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from tcms_daq.crossval import contiguous_blocks
from tcms_daq.errors import DataFormatError
from tcms_daq.samples import Samples

REVERSAL_FRACTION = 0.02  # a reversal needs the torque to leave its extreme by 2 % of the torque span
MIN_GROUPS = 3  # fewer loops/runs than this: fall back to contiguous blocks
N_BLOCKS = 6


def load_direction(torque_nm: np.ndarray, threshold_nm: float | None = None) -> np.ndarray:
    """+1 where the torque is increasing (loading towards +), −1 where decreasing, by turning points.

    A turning point is accepted once the torque has moved ``threshold_nm`` (default 2 % of the span) away
    from the running extreme; the samples after the extreme get the new direction from the first one that has
    left the extreme by more than three times the torque noise (a hold at the tip stays on the branch it ends), so
    sensor noise never flips it. Samples before the first clear movement get the first direction found.
    """
    t = np.asarray(torque_nm, dtype=float)
    n = len(t)
    if n == 0:
        return np.zeros(0, dtype=np.int8)
    noise_nm = 3.0 * torque_noise_nm(t)
    span = float(np.ptp(t))
    h = threshold_nm if threshold_nm is not None else max(REVERSAL_FRACTION * span, 1e-12)
    d = 0
    hi = lo = ext = float(t[0])
    hi_i = lo_i = ext_i = 0
    first = 0
    turns: list[int] = []
    for i in range(1, n):
        v = float(t[i])
        if d == 0:
            if v > hi:
                hi, hi_i = v, i
            if v < lo:
                lo, lo_i = v, i
            if hi - lo > h:
                d = first = 1 if hi_i > lo_i else -1
                ext, ext_i = (hi, hi_i) if d == 1 else (lo, lo_i)
        elif d == 1:
            if v > ext:
                ext, ext_i = v, i
            elif ext - v > h:
                turns.append(ext_i + 1)
                d, ext, ext_i = -1, v, i
        else:
            if v < ext:
                ext, ext_i = v, i
            elif v - ext > h:
                turns.append(ext_i + 1)
                d, ext, ext_i = 1, v, i
    if d == 0:
        return np.full(n, 1 if t[-1] >= t[0] else -1, dtype=np.int8)
    turns = [tip_departure(t, i, noise_nm) for i in turns]
    out = np.empty(n, dtype=np.int8)
    bounds = [0, *turns, n]
    sign = first
    for a, b in zip(bounds[:-1], bounds[1:], strict=True):
        out[a:b] = sign
        sign = -sign
    return out


def torque_noise_nm(torque_nm: np.ndarray) -> float:
    """Standard deviation of the torque's sample noise from its second differences (zero on ramps and holds):
    1.4826·MAD(Δ²T)/√6."""
    if len(torque_nm) < 5:
        return 0.0
    d2 = np.diff(torque_nm, 2)
    return float(1.4826 * np.median(np.abs(d2 - np.median(d2))) / np.sqrt(6.0))


def tip_departure(t: np.ndarray, first_after: int, band_nm: float) -> int:
    """The first row of a new branch: the first row after the extreme (row ``first_after − 1``) that has left the
    hold at the tip by more than the noise band, and the next row too, so a hold at the tip stays on the branch it
    ends (the reducer only turns when the torque moves back). The hold's level is the median of the rows around the
    extreme that stay within twice the band of it. (Measured from the extreme itself, the hold's highest noise
    reading, a reading of the hold one noise sigma low had already left it: a 0.2 s hold at 50 Hz turned up to 9
    rows early, and a 2″ backlash stood 2″ off on those rows in the service's closed loop.)"""
    ext = t[first_after - 1]
    start = max(first_after - 51, 0)
    before = t[start:first_after - 1]
    end = first_after
    while end < len(t) and end - first_after < 50 and abs(t[end] - ext) <= 2.0 * band_nm:
        end += 1
    level = float(np.median(np.concatenate((before[np.abs(before - ext) <= 2.0 * band_nm], t[first_after - 1:end]))))
    for i in range(first_after, min(len(t), first_after + 50)):
        if abs(t[i] - level) > band_nm and (i + 1 == len(t) or abs(t[i + 1] - level) > band_nm):
            return i
    return first_after


def reversals(direction: np.ndarray) -> np.ndarray:
    """Row indices where the load direction changes (the first row of each new branch)."""
    return np.flatnonzero(np.diff(direction) != 0) + 1


def branch_starts(direction: np.ndarray) -> np.ndarray:
    """First row of every load branch, 0 included."""
    return np.concatenate(([0], reversals(direction)))


def _moving_sum(x: np.ndarray, w: int) -> np.ndarray:
    c = np.concatenate(([0.0], np.cumsum(x)))
    n = len(x)
    lo = np.clip(np.arange(n) - w // 2, 0, n)
    hi = np.clip(np.arange(n) + w // 2 + 1, 0, n)
    return c[hi] - c[lo]


def local_slope(torque_nm: np.ndarray, angle_arcsec: np.ndarray, segments: np.ndarray,
                window: int) -> np.ndarray:
    """dθ/dT in ″/N·m of a trace by moving-window regression of angle on torque (robust to torque noise).

    Windows where the torque barely moves (dwells) get the slope of the nearest window that moves.
    """
    slope = np.full(len(torque_nm), np.nan)
    for seg in np.unique(segments):
        idx = np.flatnonzero(segments == seg)
        if len(idx) < 3:
            continue
        t = torque_nm[idx]
        a = angle_arcsec[idx]
        w = max(3, min(window, len(idx)))
        cnt = _moving_sum(np.ones(len(idx)), w)
        mt = _moving_sum(t, w) / cnt
        ma = _moving_sum(a, w) / cnt
        tt = _moving_sum(t * t, w) / cnt - mt * mt
        ta = _moving_sum(t * a, w) / cnt - mt * ma
        span = float(np.ptp(t)) or 1.0
        ok = tt > (1e-4 * span) ** 2
        s = np.where(ok, ta / np.where(ok, tt, 1.0), np.nan)
        slope[idx] = s
    bad = ~np.isfinite(slope)
    if bad.all():
        return np.zeros(len(torque_nm))
    if bad.any():
        good = np.flatnonzero(~bad)
        slope[bad] = np.interp(np.flatnonzero(bad), good, slope[good])
    return slope


def history_free_curve(torque_nm: np.ndarray, angle_arcsec: np.ndarray, direction: np.ndarray
                       ) -> tuple[np.ndarray, np.ndarray]:
    """(torque grid N·m, angle ″): the history-free part of a torque–angle trace, the mean of its loading and its
    unloading curve (each the angle's mean in equal-width torque bins, at the bins' mean torque, on a common grid,
    once each branch's smooth level against it is taken out: :func:`_direction_curve`).
    A friction loop that depends on the torque increments (Dahl, a play) is odd in the load direction and drops
    out; what stays is the spring. Where one direction does not reach, the other is used with the half-width of
    the loop at the nearest torque both reach; a trace loaded in one direction is its own curve. The first branch
    is left out when its direction has others: it starts from whatever state the friction was left in, not on the
    loop (a virgin start on the simulated bench is 17″ off it, and its share of the bins' means put a 6 N·m torque
    offset at −5 … −15 %). The curve is continued by a torque span at each end, straight with the slope of its last
    2 % of torque, so it can be read beyond the trace."""
    t = np.asarray(torque_nm, dtype=float)
    a = np.asarray(angle_arcsec, dtype=float)
    direction = np.asarray(direction)
    lo, hi = float(t.min()), float(t.max())
    if not hi > lo:
        return np.array([lo, lo + 1.0]), np.full(2, float(np.mean(a)))
    starts = branch_starts(direction)
    if len(starts) > 1 and np.count_nonzero(direction[starts] == direction[0]) > 1:
        rest = slice(int(starts[1]), None)
        t, a, direction = t[rest], a[rest], direction[rest]
    return _continued(*_mean_of_directions(t, a, direction, lo, hi))


def _continued(grid: np.ndarray, curve: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(grid, curve)`` with a point one span beyond each end, on the straight line of its last 2 % of torque."""
    span = float(grid[-1] - grid[0])
    if not span > 0:
        return grid, curve
    ends = []
    for end, far in ((0, grid[0] - span), (-1, grid[-1] + span)):
        near = np.flatnonzero(np.abs(grid - grid[end]) <= 0.02 * span)
        if len(near) < 2:
            near = np.array([0, 1]) if end == 0 else np.array([len(grid) - 2, len(grid) - 1])
        slope = float(np.polyfit(grid[near], curve[near], 1)[0])
        ends.append((far, curve[end] + slope * (far - grid[end])))
    return (np.concatenate(([ends[0][0]], grid, [ends[1][0]])),
            np.concatenate(([ends[0][1]], curve, [ends[1][1]])))


def _mean_of_directions(t: np.ndarray, a: np.ndarray, direction: np.ndarray, lo: float, hi: float
                        ) -> tuple[np.ndarray, np.ndarray]:
    curves = []
    branch = np.cumsum(np.concatenate(([0], np.diff(direction) != 0)))
    for sign in (1, -1):
        rows = np.flatnonzero(direction == sign)
        if len(rows) < 2:
            continue
        curves.append(_direction_curve(t[rows], a[rows], branch[rows], lo, hi))
    grid = np.unique(np.concatenate([c for c, _ in curves]))
    if len(curves) == 1:
        return grid, np.interp(grid, *curves[0])
    (cu, mu), (cd, md) = curves
    up = np.where((grid >= cu[0]) & (grid <= cu[-1]), np.interp(grid, cu, mu), np.nan)
    down = np.where((grid >= cd[0]) & (grid <= cd[-1]), np.interp(grid, cd, md), np.nan)
    both = np.isfinite(up) & np.isfinite(down)
    if not both.any():
        return grid, np.where(np.isfinite(up), up, down)
    half = np.interp(grid, grid[both], 0.5 * (up - down)[both])  # the loop's half-width, held beyond the overlap
    return grid, np.where(np.isfinite(up), up - half, down + half)


BRANCH_LEVEL_SPAN = 0.02  # a branch's level against its direction's curve is smoothed over ± this share of the span
BRANCH_LEVEL_PASSES = 2


def _direction_curve(t: np.ndarray, a: np.ndarray, branch: np.ndarray, lo: float, hi: float
                     ) -> tuple[np.ndarray, np.ndarray]:
    """(bin centres N·m, angle ″): the curve of one load direction from its branches (``branch``: a label per row),
    the mean angle in equal-width torque bins after each branch's smooth level against the curve is taken out, at
    the level of the typical branch.

    The branches of one direction need not lie on one curve: a friction loop remembers where a branch began (the
    RV-110E's Dahl loop over 539 N·m of torque: in the service's programme the branch that starts at the reversal at
    zero torque between the two rates lies 16″ off the others 100 N·m after it, and the next one 3.7 … 1.2″ over its
    first 700 N·m). A bin's plain mean then depends on which branches have a sample in it, and a branch ramped
    faster has one in every third 4 N·m bin only (12 N·m a sample at 600 N·m/s and 50 Hz): the curve came out with a
    saw tooth of that period, 0.25″ RMS about its smooth (cubic) trend, and the torque offset's signature read off
    it was 0.28″ RMS wrong against a signature of 0.42″ (8 N·m; the offset not named over the service). Each
    branch's level is its deviation from the curve, smoothed by a local straight line over ±``BRANCH_LEVEL_SPAN`` of
    the span (at least twice the largest typical step of a branch, so every branch has samples in the window); the
    samples less their level lie on one curve whatever bins they fall in (0.016″ RMS about its trend), and the curve
    is put at the median of the branches' levels, so a branch that began elsewhere does not bend it by its share of
    a mean (its share put the offset 2.5 % low)."""
    n_bins = int(np.clip(len(t) // 8, 8, 400))
    index = np.clip(((t - lo) / (hi - lo) * n_bins).astype(int), 0, n_bins - 1)
    count = np.bincount(index, minlength=n_bins).astype(float)
    used = count > 0
    centre = np.bincount(index, weights=t, minlength=n_bins)[used] / count[used]
    labels, rows_of = np.unique(branch, return_inverse=True)
    if len(labels) < 2:
        return centre, np.bincount(index, weights=a, minlength=n_bins)[used] / count[used]
    steps = [np.median(np.abs(np.diff(t[rows_of == k]))) for k in range(len(labels)) if np.sum(rows_of == k) > 1]
    half_window = max(BRANCH_LEVEL_SPAN * (hi - lo), 2.0 * float(max(steps, default=0.0)))
    level = np.zeros_like(a)
    members = [np.flatnonzero(rows_of == k) for k in range(len(labels))]
    for _ in range(BRANCH_LEVEL_PASSES):
        mean = np.bincount(index, weights=a - level, minlength=n_bins)[used] / count[used]
        deviation = a - np.interp(t, centre, mean)
        for rows in members:
            level[rows] = _local_line(t[rows], deviation[rows], half_window)
    # the typical branch: each bin at the median of the branches' levels there
    at = np.full((len(members), len(centre)), np.nan)
    for k, rows in enumerate(members):
        order = rows[np.argsort(t[rows], kind="stable")]
        inside = (centre >= t[order[0]]) & (centre <= t[order[-1]])
        at[k, inside] = np.interp(centre[inside], t[order], level[order])
    covered = np.isfinite(at).any(axis=0)
    typical = np.zeros(len(centre))
    typical[covered] = np.nanmedian(at[:, covered], axis=0)
    mean = np.bincount(index, weights=a - level, minlength=n_bins)[used] / count[used]
    return centre, mean + typical


def _local_line(x: np.ndarray, y: np.ndarray, half_width: float) -> np.ndarray:
    """y smoothed by a straight line fitted over |x' − x| ≤ ``half_width`` at each x (its value there)."""
    order = np.argsort(x, kind="stable")
    xs, ys = x[order], y[order]
    x0 = float(np.mean(xs))
    xc = xs - x0
    sums = [np.concatenate(([0.0], np.cumsum(v))) for v in (np.ones_like(xc), xc, ys, xc * xc, xc * ys)]
    lo = np.searchsorted(xs, xs - half_width, side="left")
    hi = np.searchsorted(xs, xs + half_width, side="right")
    n, sx, sy, sxx, sxy = (c[hi] - c[lo] for c in sums)
    var = n * sxx - sx * sx
    flat = var <= 1e-12 * np.maximum(n * n, 1.0) * max(half_width, 1e-12) ** 2
    slope = np.where(flat, 0.0, (n * sxy - sx * sy) / np.where(flat, 1.0, var))
    out = np.empty_like(y)
    out[order] = (sy - slope * sx) / n + slope * xc
    return out


def time_segments(time_s: np.ndarray, run_id: np.ndarray | None) -> np.ndarray:
    """Labels of stretches with continuous, increasing time (a new run or a time jump starts a new one)."""
    n = len(time_s)
    if n == 0:
        return np.zeros(0, dtype=int)
    dt = np.diff(time_s)
    pos = dt[dt > 0]
    typical = float(np.median(pos)) if len(pos) else 1.0
    brk = (dt <= 0) | (dt > 20 * typical)
    if run_id is not None:
        brk |= np.diff(run_id) != 0
    return np.concatenate(([0], np.cumsum(brk))).astype(int)


def loop_groups(direction: np.ndarray, segments: np.ndarray) -> np.ndarray:
    """Loops between torque minima (reversals from unloading to loading), never across segments.

    Pieces shorter than 30 % of the median loop are merged into their neighbour in the same segment.
    """
    n = len(direction)
    start = np.zeros(n, dtype=bool)
    start[0] = True
    start[1:] |= (direction[1:] == 1) & (direction[:-1] == -1)
    start[1:] |= segments[1:] != segments[:-1]
    labels = np.cumsum(start) - 1
    counts = np.bincount(labels)
    if len(counts) > 2:
        typical = float(np.median(counts))
        seg_of = segments[np.flatnonzero(start)]
        merged = np.arange(len(counts))
        for k in range(len(counts)):
            if counts[k] < 0.3 * typical:
                if k > 0 and seg_of[k - 1] == seg_of[k]:
                    merged[k] = merged[k - 1]
                elif k + 1 < len(counts) and seg_of[k + 1] == seg_of[k]:
                    merged[k] = k + 1
        # resolve forward merges (k -> k+1) transitively
        for k in range(len(counts) - 1, -1, -1):
            if merged[k] == k + 1:
                merged[k] = merged[k + 1]
        labels = np.unique(merged, return_inverse=True)[1][labels]
    return labels.astype(int)


def block_groups(n: int, n_blocks: int = N_BLOCKS) -> np.ndarray:
    """Contiguous blocks for data without loops or runs: ``n_blocks``, but at least 3 rows a block (≥ 2 blocks)."""
    return contiguous_blocks(n, max(2, min(n_blocks, n // 3 if n >= 6 else 2)))


@dataclass
class DesignData:
    """Aligned arrays of one measured/simulated comparison; r = measured − simulated (″)."""

    time_s: np.ndarray
    has_time: bool
    torque_nm: np.ndarray
    sim_angle_arcsec: np.ndarray
    measured_angle_arcsec: np.ndarray
    direction: np.ndarray
    slope_arcsec_per_nm: np.ndarray
    segments: np.ndarray
    groups: np.ndarray
    group_kind: str  # "runs" | "loops" | "blocks"
    signal_period_arcsec: float

    @property
    def residual_arcsec(self) -> np.ndarray:
        return self.measured_angle_arcsec - self.sim_angle_arcsec

    @cached_property
    def elapsed_s(self) -> np.ndarray:
        """Time since the first row (s): the clock the time-dependent effects run on."""
        return self.time_s - self.time_s[0]

    @cached_property
    def history_free(self) -> tuple[np.ndarray, np.ndarray]:
        """The simulated curve's history-free part (:func:`history_free_curve`), computed once."""
        return history_free_curve(self.torque_nm, self.sim_angle_arcsec, self.direction)

    @cached_property
    def history_free_on_rows(self) -> np.ndarray:
        """The history-free part at each row's torque (″)."""
        return np.interp(self.torque_nm, *self.history_free)

    @cached_property
    def segment_rows(self) -> list[np.ndarray]:
        """Row indices of each time-continuous segment, in segment order (computed once)."""
        order = np.argsort(self.segments, kind="stable")
        return np.split(order, np.flatnonzero(np.diff(self.segments[order])) + 1)

    @cached_property
    def _angle_interpolants(self) -> dict[int, Callable[[np.ndarray], np.ndarray]]:
        from scipy.interpolate import PchipInterpolator

        out: dict[int, Callable[[np.ndarray], np.ndarray]] = {}
        for idx in self.segment_rows:
            t, a = self.time_s[idx], self.sim_angle_arcsec[idx]
            if len(idx) >= 2 and np.all(np.diff(t) > 0):
                out[int(self.segments[idx[0]])] = PchipInterpolator(t, a, extrapolate=False)
            else:  # time not strictly increasing: linear pieces
                out[int(self.segments[idx[0]])] = _linear_pieces(t, a)
        return out

    def angle_interpolant(self, segment: int) -> Callable[[np.ndarray], np.ndarray]:
        """The simulated angle (″) of time-continuous segment ``segment`` as a function of time within it:
        monotone cubic pieces (PCHIP, no overshoot at a reversal), built once per segment."""
        return self._angle_interpolants[segment]

    def __len__(self) -> int:
        return len(self.torque_nm)


def _linear_pieces(x: np.ndarray, y: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
    def at(q: np.ndarray) -> np.ndarray:
        return np.asarray(np.interp(q, x, y), dtype=float)

    return at


def build_design(measured: Samples, simulated: Samples, *, signal_period_arcsec: float = 72.0,
                 has_time: bool = True, torque_tolerance_nm: float | None = None,
                 time_tolerance_s: float = 1e-6) -> DesignData:
    """Check alignment (same rows, same order) and derive the signals. Raises DataFormatError."""
    n = len(measured)
    if len(simulated) != n:
        raise DataFormatError(f"measured has {n} rows, simulated has {len(simulated)}: they must be the same rows")
    if n < 12:
        raise DataFormatError(f"only {n} rows: the discrepancy workflow needs at least 12 aligned samples")
    if not (signal_period_arcsec > 0 and np.isfinite(signal_period_arcsec)):
        raise DataFormatError(f"signal period must be a finite number > 0 arcsec, got {signal_period_arcsec}")
    for side, samples in (("measured", measured), ("simulated", simulated)):
        columns = (("torque_nm", samples.torque_nm), ("angle_arcsec", samples.angle_arcsec)) + (
            (("time_s", samples.time_s),) if has_time else ())
        for name, values in columns:
            bad = np.flatnonzero(~np.isfinite(values))
            if bad.size:
                raise DataFormatError(f"{side} {name} is not finite at row {int(bad[0]) + 2} ({values[bad[0]]!r}) "
                                      f"and {bad.size - 1} more: the workflow needs finite samples")
    if has_time:
        dt = np.abs(measured.time_s - simulated.time_s)
        if np.any(dt > time_tolerance_s * max(1.0, float(np.max(np.abs(measured.time_s))))):
            i = int(np.argmax(dt))
            raise DataFormatError(
                f"time_s differs at row {i + 2}: measured {float(measured.time_s[i]):.9g}, simulated {float(simulated.time_s[i]):.9g}"
            )
    span = float(np.ptp(measured.torque_nm))
    tol = torque_tolerance_nm if torque_tolerance_nm is not None else max(1e-6 * max(span, 1.0), 1e-9)
    dtq = np.abs(measured.torque_nm - simulated.torque_nm)
    if np.any(dtq > tol):
        i = int(np.argmax(dtq))
        raise DataFormatError(
            f"torque_nm differs at row {i + 2}: measured {float(measured.torque_nm[i]):.9g}, "
            f"simulated {float(simulated.torque_nm[i]):.9g} (files are not aligned)"
        )
    if span <= 0:
        raise DataFormatError("torque_nm is constant: there is no torque–angle curve to compare")
    run_id = measured.extra.get("run_id")
    if run_id is None:
        run_id = simulated.extra.get("run_id")
    time_s = measured.time_s if has_time else np.arange(n, dtype=float)
    segments = time_segments(time_s, run_id) if has_time else (
        np.concatenate(([0], np.cumsum(np.diff(run_id) != 0))).astype(int) if run_id is not None
        else np.zeros(n, dtype=int))
    torque = measured.torque_nm
    direction = load_direction(torque)
    theta = simulated.angle_arcsec
    window = 3  # central differences: the lost-motion zone is crossed in a few samples
    slope = local_slope(torque, theta, segments, window)
    groups, kind = None, ""
    if run_id is not None:
        labels = np.unique(run_id, return_inverse=True)[1]
        if labels.max() + 1 >= MIN_GROUPS:
            groups, kind = labels.astype(int), "runs"
    if groups is None:
        loops = loop_groups(direction, segments)
        if loops.max() + 1 >= MIN_GROUPS:
            groups, kind = loops, "loops"
        else:
            groups, kind = block_groups(n), "blocks"
    return DesignData(time_s, has_time, torque, theta, measured.angle_arcsec, direction.astype(float), slope,
                      segments, groups, kind, float(signal_period_arcsec))

"""The turning point of a loop (the tip, where a branch ends and the next begins), estimated from the flanks on
either side, not from the extreme sample.

The largest sample of a noisy record overshoots the torque reached; a smoothed record undershoots it at a sharp
(no-hold) tip, by a quarter of the torque the smoothing window spans; the sample nearest the tip misses it by up
to half a sample step. Both bias a rigidity secant that ends at the tip. Here each flank (``n`` samples before
and after the extreme of the smoothed torque) gets least-squares lines of torque and angle in time (time is
exact, so noisy torque causes no errors-in-variables bias):
- a sharp tip (torque rising into it and falling out of it by more than noise): the torque lines intersect at
  the tip time t*; the tip torque is their value there and the tip angle the mean of the two angle lines at t*;
- a held tip (a flank flat within its noise): the mean torque and angle of the flat flank(s).
The compliance dθ/dT of each flank lets a branch be read a little below its tip (the other tip of a loop side).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

MIN_FLANK_SAMPLES = 3
QUADRATIC_FROM = 6  # flank angle fits are parabolas from this many samples on
FLAT_NOISE_FACTOR = 4.0  # a flank whose torque changes by less than this × its fit's noise is a hold


@dataclass(frozen=True)
class TipPoint:
    """A turning point: signed torque (N·m) and angle (arcsec) at the tip, dθ/dT (arcsec per N·m) of the
    flank before and after it (NaN on a held flank)."""

    index: int
    torque_nm: float
    angle_arcsec: float
    compliance_before: float
    compliance_after: float

    def sharp(self, before: bool) -> bool:
        """Whether the flank before (after) the tip moves, i.e. the tip is not held on that side."""
        return bool(np.isfinite(self.compliance_before if before else self.compliance_after))

    def angle_on_flank(self, level_nm: float, before: bool) -> float:
        """θ (arcsec) at a torque ``level_nm`` a little short of the tip on one flank (linear in torque)."""
        c = self.compliance_before if before else self.compliance_after
        if not np.isfinite(c):
            return self.angle_arcsec
        return float(self.angle_arcsec + c * (level_nm - self.torque_nm))


Flank = tuple[float, float, float, float, float, float, slice]  # torque a, b; angle a, b; change; noise; samples


def _line(t: np.ndarray, y: np.ndarray, degree: int = 1) -> tuple[float, float, float]:
    """Least-squares polynomial y = a + b·t (+ c·t²): (a, b, residual standard deviation); a and b are the value
    and the slope at t = 0."""
    design = np.column_stack([t**k for k in range(degree + 1)])
    coef, *_ = np.linalg.lstsq(design, y, rcond=None)
    resid = y - design @ coef
    dof = max(t.size - degree - 1, 1)
    return float(coef[0]), float(coef[1]), float(np.sqrt(resid @ resid / dof))


def _at(t: np.ndarray, y: np.ndarray, t_star: float) -> float:
    """The flank's angle fit (a parabola from QUADRATIC_FROM samples on, else a line) at ``t_star``."""
    degree = 2 if t.size >= QUADRATIC_FROM else 1
    design = np.column_stack([t**k for k in range(degree + 1)])
    coef, *_ = np.linalg.lstsq(design, y, rcond=None)
    return float(sum(c * t_star**k for k, c in enumerate(coef)))


def _within_band(torque_smooth_nm: np.ndarray, index: int, lo: int, hi: int, span_nm: float) -> tuple[int, int]:
    """The flanks' ends [lo, hi) cut to the contiguous samples around ``index`` whose smoothed torque stays within
    ``span_nm`` of the tip's (at least MIN_FLANK_SAMPLES on each side)."""
    level = float(torque_smooth_nm[index])
    inside = np.abs(torque_smooth_nm[lo:hi] - level) <= span_nm
    k = index - lo
    left = np.flatnonzero(~inside[: k + 1][::-1])
    right = np.flatnonzero(~inside[k:])
    new_lo = index - int(left[0]) + 1 if left.size else lo
    new_hi = index + int(right[0]) if right.size else hi
    return (min(new_lo, max(lo, index - MIN_FLANK_SAMPLES + 1)),
            max(new_hi, min(hi, index + MIN_FLANK_SAMPLES)))


def _value(t: np.ndarray, y: np.ndarray, t_star: float) -> float:
    a, b, _ = _line(t, y)
    return a + b * t_star


def _hinge(time_s: np.ndarray, torque_nm: np.ndarray, index: int, lo: int, hi: int) -> tuple[slice, slice, float]:
    """Two torque lines meeting at a sharp tip: (samples of the rising flank, of the falling flank, the time t* they
    meet, from the extreme sample's time). The extreme sample lies on one flank only (the true tip falls between
    two samples): it is given to the flank whose lines then meet on its side of it, else to the better fit. With
    dense samples this changes nothing measurable; with a few samples per flank (coarse sampling) counting it on
    both flanks pulls the tip down by up to a quarter of a sample's torque step."""
    t0 = float(time_s[index])
    candidates = []
    for b_sl, a_sl, side in ((slice(lo, index + 1), slice(index + 1, hi), 1.0),
                             (slice(lo, index), slice(index, hi), -1.0)):
        tb, ta = time_s[b_sl] - t0, time_s[a_sl] - t0
        if tb.size < 2 or ta.size < 2:
            continue
        a1, b1, s1 = _line(tb, torque_nm[b_sl])
        a2, b2, s2 = _line(ta, torque_nm[a_sl])
        if b1 == b2:
            continue
        t_star = (a2 - a1) / (b1 - b2)
        ssr = s1 * s1 * max(tb.size - 2, 1) + s2 * s2 * max(ta.size - 2, 1)
        candidates.append((side * t_star < 0.0, ssr, b_sl, a_sl, t_star))  # False (consistent) sorts first
    if not candidates:
        b_sl, a_sl = slice(lo, index + 1), slice(index, hi)
        a1, b1, _ = _line(time_s[b_sl] - t0, torque_nm[b_sl])
        a2, b2, _ = _line(time_s[a_sl] - t0, torque_nm[a_sl])
        t_star = (a2 - a1) / (b1 - b2) if b1 != b2 else 0.0
    else:
        _, _, b_sl, a_sl, t_star = min(candidates, key=lambda c: (c[0], c[1]))
    return b_sl, a_sl, float(np.clip(t_star, time_s[lo] - t0, time_s[hi - 1] - t0))


def tip_point(time_s: np.ndarray, torque_nm: np.ndarray, angle_arcsec: np.ndarray, index: int, n: int,
              torque_noise_nm: float, torque_smooth_nm: np.ndarray | None = None,
              span_nm: float = math.inf) -> TipPoint:
    """The tip at sample ``index`` (the extreme of the smoothed torque) from at most ``n`` samples on each flank:
    those whose smoothed torque ``torque_smooth_nm`` stays within ``span_nm`` of the tip's, so the step below the
    last ramp of a staircase (a hold, flat torque) does not bend the flank's line."""
    n = max(int(n), MIN_FLANK_SAMPLES)
    size = torque_nm.size
    lo, hi = max(0, index - n + 1), min(size, index + n)
    if torque_smooth_nm is not None and math.isfinite(span_nm):
        lo, hi = _within_band(torque_smooth_nm, index, lo, hi, span_nm)
    t0 = float(time_s[index])
    sign = 1.0 if torque_nm[index] >= 0.0 else -1.0
    flanks: list[Flank | None] = []
    for sl in (slice(lo, index + 1), slice(index, hi)):
        t = time_s[sl] - t0
        if t.size < 2:
            flanks.append(None)
            continue
        a_t, b_t, s_t = _line(t, torque_nm[sl])
        a_q, b_q, _ = _line(t, angle_arcsec[sl])
        change = b_t * float(t[-1] - t[0])
        # the floor keeps a noiseless hold (rounding-level slopes) flat
        noise = max(s_t, torque_noise_nm, 1e-9 * abs(float(torque_nm[index]))) / np.sqrt(t.size)
        flanks.append((a_t, b_t, a_q, b_q, change, noise, sl))
    before, after = flanks

    def moving(f: Flank | None, direction: float) -> bool:
        return f is not None and direction * sign * f[4] > FLAT_NOISE_FACTOR * f[5]

    def compliance(f: Flank | None, moves: bool) -> float:
        return float(f[3] / f[1]) if f is not None and moves and f[1] != 0.0 else float("nan")

    rising, falling = moving(before, 1.0), moving(after, -1.0)
    if rising and falling and before is not None and after is not None:
        b_sl, a_sl, t_star = _hinge(time_s, torque_nm, index, lo, hi)
        torque_tip = _value(time_s[b_sl] - t0, torque_nm[b_sl], t_star)
        angle_tip = 0.5 * (_at(time_s[b_sl] - t0, angle_arcsec[b_sl], t_star)
                           + _at(time_s[a_sl] - t0, angle_arcsec[a_sl], t_star))
    else:
        flat = [f for f, moves in ((before, rising), (after, falling)) if f is not None and not moves]
        sel = np.concatenate([np.arange(size)[f[6]] for f in flat]) if flat else np.array([index])
        torque_tip = float(np.mean(torque_nm[sel]))
        angle_tip = float(np.mean(angle_arcsec[sel]))
    return TipPoint(index, float(torque_tip), float(angle_tip), compliance(before, rising), compliance(after, falling))

"""Reducer physics for the validation families, written from the physics of a loaded gear train and not from the
evaluation's code: nothing here imports ``tcms_daq.analysis``.

A reducer's output twist θ (arcsec) under an input torque history T(t) (N·m) is the sum of
- an elastic part: 60·T/K± (K in N·m/arcmin, K₊ for T > 0 and K₋ for T < 0: asymmetric stiffness); a harmonic
  drive adds a softer first region, (60/K₁ − 60/K₃)·T₁·tanh(T/T₁) (K₁ < K₃ below about T₁);
- a lost-motion zone, the play taken up around zero torque: soft (L/2)·tanh(T/T_b) or hard (L/2)·clip(T/T_b, ±1)
  (a kink where the teeth come into contact);
- a friction state f that sticks after every reversal and slides once the friction is overcome, saturating at
  ∓B/2 on loading/unloading (the loading branch lies below the unloading one):
  * Dahl (1968): df/dT = −s·(B/2 + s·f)/T_z, s = sign(dT/dt): exponential in the torque since the reversal;
  * Prandtl–Ishlinskii: f = Σ wᵢ·(pᵢ − T) over play operators pᵢ of thresholds rᵢ (pᵢ = max(T − rᵢ, min(T + rᵢ,
    pᵢ_prev))), 2·Σ wᵢ rᵢ = B: piecewise linear, with corners;
  * Bouc–Wen (1976): dz/dT = A − (β·sign(s·z) + γ)·|z|ⁿ·s … with z_max = 1, f = −(B/2)·z: smooth, its sharpness n;
  * LuGre-like: a Dahl state whose saturation depends on the sliding speed (a Stribeck factor on B) plus a
    velocity term, the viscous lag −c·dT/dt (rate dependent: the loop widens with the loading rate).
All four operators are solved in closed form (or on a fine tabulated master curve) along each monotonic torque
segment, so a run's true twist is exact at every sample; the truth of the results is computed from the dense
noise-free path, branch by branch, with the definitions of the measurands (DESIGN §2), not by the evaluation.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

ARCSEC_PER_ARCMIN = 60.0


@dataclass(frozen=True)
class Reducer:
    """One reducer's true physics (torques in N·m, angles in arcsec, stiffness in N·m/arcmin)."""

    rated_torque_nm: float
    rigidity_pos_nm_per_arcmin: float
    rigidity_neg_nm_per_arcmin: float
    zone: str  # "soft" | "hard"
    zone_width_arcsec: float  # L
    zone_torque_nm: float  # T_b
    friction: str  # "dahl" | "play" | "bouc-wen" | "lugre"
    friction_width_arcsec: float  # B
    friction_torque_nm: float  # T_z: torque over which friction saturates after a reversal
    bouc_wen_n: float = 1.0
    bouc_wen_beta_share: float = 0.5  # β/(β + γ)
    viscous_arcsec_s_per_nm: float = 0.0  # LuGre velocity term c: θ_v = −c·dT/dt
    stribeck_gain: float = 0.0  # LuGre: B·(1 + g·exp(−(rate/v_s)²))
    stribeck_rate_nm_per_s: float = 100.0
    soft_region_torque_nm: float = 0.0  # harmonic drive T₁ (0: none)
    soft_region_ratio: float = 1.0  # K₁/K₃


@dataclass(frozen=True)
class Profile:
    """The commanded torque: 0 → −A, ``loops`` × (−A → +A → −A), → 0, at ``rate_nm_per_s``; ``tip_hold_s`` at
    every ±A; ``steps`` > 0 makes each branch a staircase of that many equal steps held ``step_hold_s``."""

    amplitude_nm: float
    loops: int
    rate_nm_per_s: float
    tip_hold_s: float = 0.0
    steps: int = 0
    step_hold_s: float = 0.0

    def waypoints(self) -> tuple[np.ndarray, np.ndarray]:
        """(time_s, torque_nm) corners of the piecewise linear commanded torque."""
        a = self.amplitude_nm
        tips = [-a] + [a, -a] * self.loops
        t_way, q_way = [0.0], [0.0]

        def go(target: float, hold: float) -> None:
            t_way.append(t_way[-1] + abs(target - q_way[-1]) / self.rate_nm_per_s)
            q_way.append(target)
            if hold > 0.0:
                t_way.append(t_way[-1] + hold)
                q_way.append(target)

        go(tips[0], self.tip_hold_s)
        for prev, tip in zip(tips[:-1], tips[1:], strict=True):
            if self.steps > 0:
                for level in np.linspace(prev, tip, self.steps + 1)[1:-1]:
                    go(float(level), self.step_hold_s)
            go(tip, self.tip_hold_s)
        go(0.0, 0.0)
        return np.asarray(t_way), np.asarray(q_way)


def _elastic_and_zone(torque: np.ndarray, r: Reducer) -> np.ndarray:
    k = np.where(torque >= 0.0, r.rigidity_pos_nm_per_arcmin, r.rigidity_neg_nm_per_arcmin)
    theta = ARCSEC_PER_ARCMIN * torque / k
    if r.soft_region_torque_nm > 0.0:
        k3 = 0.5 * (r.rigidity_pos_nm_per_arcmin + r.rigidity_neg_nm_per_arcmin)
        extra = ARCSEC_PER_ARCMIN * (1.0 / (r.soft_region_ratio * k3) - 1.0 / k3)
        theta = theta + extra * r.soft_region_torque_nm * np.tanh(torque / r.soft_region_torque_nm)
    x = torque / r.zone_torque_nm
    shape = np.tanh(x) if r.zone == "soft" else np.clip(x, -1.0, 1.0)
    return theta + 0.5 * r.zone_width_arcsec * shape


def _segments(torque: np.ndarray) -> list[tuple[int, int, int]]:
    """(first, last, direction) of the monotonic runs of a dense torque path; neighbours share their end point;
    direction 0 is a hold."""
    d = np.sign(np.diff(torque)).astype(int)
    change = np.flatnonzero(np.diff(d)) + 1
    starts = np.concatenate(([0], change))
    ends = np.concatenate((change, [d.size]))
    return [(int(a), int(b), int(d[a])) for a, b in zip(starts, ends, strict=True)]


class _BoucWenCurve:
    """The Bouc–Wen state on a loading segment, dz/dT = A − (β·sign(z) + γ)|z|ⁿ with z_max = 1, A = 1/T_z: the
    master curve X(z) = ∫dz/g(z) tabulated once; a segment from z₀ reaches Z(X(z₀) + ΔT). Unloading mirrors it."""

    def __init__(self, r: Reducer) -> None:
        a = 1.0 / r.friction_torque_nm
        beta = r.bouc_wen_beta_share * a
        gamma = a - beta
        n = r.bouc_wen_n
        # z from −1 to 1, refined towards +1 where g → 0 (X → ∞ logarithmically)
        gap = np.geomspace(2.0, 1e-12, 40_000)
        z = 1.0 - gap
        g = a - (beta * np.sign(z) + gamma) * np.abs(z) ** n
        g = np.maximum(g, 1e-300)
        inv = 1.0 / g
        x = np.concatenate(([0.0], np.cumsum(0.5 * (inv[1:] + inv[:-1]) * np.diff(z))))
        self.z, self.x = z, x

    def advance(self, z0: float, travel: np.ndarray) -> np.ndarray:
        x0 = float(np.interp(z0, self.z, self.x))
        return np.interp(x0 + travel, self.x, self.z)


def friction_arcsec(torque: np.ndarray, r: Reducer, rate_nm_per_s: float) -> np.ndarray:
    """The friction state f (arcsec) along a dense torque path starting from rest (f = 0), segment by segment."""
    half = 0.5 * r.friction_width_arcsec
    if r.friction == "lugre":
        half *= 1.0 + r.stribeck_gain * math.exp(-((rate_nm_per_s / r.stribeck_rate_nm_per_s) ** 2))
    f = np.zeros_like(torque)
    if r.friction == "play":
        thresholds = np.linspace(0.25, 2.0, 8) * r.friction_torque_nm
        weights = half / float(np.sum(thresholds))  # 2·Σ w·r = B with equal weights
        total = np.zeros_like(torque)
        for rr in thresholds:
            p = np.empty_like(torque)
            prev = float(torque[0])
            for a, b, s in _segments(torque):
                seg = torque[a:b + 1]
                if s >= 0:
                    p[a:b + 1] = np.maximum(seg - rr, prev)
                else:
                    p[a:b + 1] = np.minimum(seg + rr, prev)
                prev = float(p[b])
            total += weights * (p - torque)
        return total
    curve = _BoucWenCurve(r) if r.friction == "bouc-wen" else None
    state = 0.0  # Dahl/LuGre: f; Bouc–Wen: z (f = −half·z)
    for a, b, s in _segments(torque):
        seg = torque[a:b + 1]
        travel = np.abs(seg - seg[0])
        if s == 0:
            f[a:b + 1] = f[a] if a > 0 else 0.0
            continue
        if curve is not None:
            z = curve.advance(s * state, travel) * s
            f[a:b + 1] = -half * z
            state = float(z[-1])
        else:
            target = -s * half
            f[a:b + 1] = target + (state - target) * np.exp(-travel / r.friction_torque_nm)
            state = float(f[b])
    return f


@dataclass(frozen=True)
class Record:
    """One run's true signals on the dense path and the readings at the sample times."""

    time_s: np.ndarray
    torque_nm: np.ndarray  # as read (gain error, noise)
    angle_arcsec: np.ndarray  # as read
    truth: dict[str, float]


def dense_path(profile: Profile, step_nm: float) -> tuple[np.ndarray, np.ndarray]:
    """(time_s, torque_nm) of the commanded profile on a fine grid: at most ``step_nm`` of torque between points,
    every corner included."""
    t_way, q_way = profile.waypoints()
    times = [np.array([t_way[0]])]
    for k in range(t_way.size - 1):
        n = max(1, int(math.ceil(abs(q_way[k + 1] - q_way[k]) / step_nm)))
        times.append(np.linspace(t_way[k], t_way[k + 1], n + 1)[1:])
    t = np.concatenate(times)
    return t, np.interp(t, t_way, q_way)


def true_twist(time_s: np.ndarray, torque_nm: np.ndarray, r: Reducer, profile: Profile) -> np.ndarray:
    """θ (arcsec) along a dense path (time_s, torque_nm) of ``profile``."""
    theta = _elastic_and_zone(torque_nm, r) + friction_arcsec(torque_nm, r, profile.rate_nm_per_s)
    if r.viscous_arcsec_s_per_nm > 0.0:
        rate = np.gradient(torque_nm, time_s)
        theta = theta - r.viscous_arcsec_s_per_nm * rate
    return theta


def truth(time_s: np.ndarray, torque_nm: np.ndarray, theta: np.ndarray, profile: Profile, rated_nm: float,
          test_torque_nm: float, lost_motion_pct: float = 3.0, interval: tuple[float, float] = (0.5, 1.0)
          ) -> dict[str, float]:
    """The measurands of the noise-free dense path, averaged over its full loops: backlash θ_B↓(0) − θ_B↑(0);
    midline m(T) = (θ_B↑(T) + θ_B↓(T))/2; lost motion m(+p·T_rated) − m(−p·T_rated); rigidity the secant of the
    midline over [lo, hi]·T_test per side (hi at most the amplitude reached), the two sides averaged."""
    a = profile.amplitude_nm
    at_tip = np.flatnonzero(np.isclose(np.abs(torque_nm), a, rtol=0, atol=1e-9 * a))
    # the tips in order: group consecutive indices (a hold is a run of them); a branch leaves a tip's last point
    groups = np.split(at_tip, np.flatnonzero(np.diff(at_tip) > 1) + 1)
    tips = [(int(g[0]), int(g[-1]), int(np.sign(torque_nm[g[0]]))) for g in groups]
    lo = interval[0] * test_torque_nm
    hi = min(interval[1] * test_torque_nm, a)
    lm = lost_motion_pct / 100.0 * rated_nm
    values: dict[str, list[float]] = {"rigidity_nm_per_arcmin": [], "lost_motion_arcsec": [], "backlash_arcsec": []}

    def branch(k: int) -> tuple[np.ndarray, np.ndarray]:
        start, stop = tips[k][1], tips[k + 1][0]
        q, th = torque_nm[start:stop + 1], theta[start:stop + 1]
        if q[-1] < q[0]:
            q, th = q[::-1], th[::-1]
        # a staircase holds: keep one point per torque (the angle of a rate-independent path is the same)
        q, keep = np.unique(q, return_index=True)
        return q, th[keep]

    for k in range(0, len(tips) - 2, 2):
        up, down = branch(k), branch(k + 1)

        def mid(level: float, up=up, down=down) -> float:
            return 0.5 * (float(np.interp(level, *up)) + float(np.interp(level, *down)))

        k_pos = (hi - lo) / (mid(hi) - mid(lo))
        k_neg = (hi - lo) / (mid(-lo) - mid(-hi))
        values["rigidity_nm_per_arcmin"].append(0.5 * ARCSEC_PER_ARCMIN * (k_pos + k_neg))
        values["lost_motion_arcsec"].append(mid(lm) - mid(-lm))
        values["backlash_arcsec"].append(float(np.interp(0.0, *down) - np.interp(0.0, *up)))
    return {name: float(np.mean(v)) for name, v in values.items()}

"""An independent generator for the uncertainty tests, built from physics (not from sim/ or the evaluation):
a reducer as a spring whose play is taken up smoothly, with Dahl friction, loaded by a triangular torque profile,
read by a torque sensor and an angle encoder whose systematic errors are drawn per run from declared standard
uncertainties, plus white noise. The truth of every result is computed here from the noise-free branches.

Twist (arcsec) at torque T on a branch of direction s (+1 loading towards +T, −1 towards −T):
    θ(T) = 60·T/K + (L/2)·tanh(T/T_b) − z,   z → s·B/2 exponentially over a torque of T_z after each reversal
so the loading branch lies below the unloading one; the loop width at zero torque is the backlash.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Reducer:
    rigidity_nm_per_arcmin: float = 300.0
    play_arcsec: float = 10.0  # L: play taken up around zero torque
    play_torque_nm: float = 15.0  # T_b
    friction_width_arcsec: float = 24.0  # B: Dahl loop width once saturated
    friction_torque_nm: float = 120.0  # T_z: torque over which friction saturates after a reversal


@dataclass(frozen=True)
class Chain:
    """Standard uncertainties (k = 1) of the readings' systematic errors, drawn once per run."""

    torque_u_rel: float = 0.002
    torque_u_zero_nm: float = 0.5
    angle_u_rel: float = 0.002
    angle_u_arcsec: float = 1.0
    interpolation_u_arcsec: float = 0.15
    signal_period_arcsec: float = 72.0

    def declaration(self) -> dict:
        """The same uncertainties as an --uncertainty file's tables."""
        return {"torque": {"u_rel": self.torque_u_rel, "u_zero_nm": self.torque_u_zero_nm},
                "angle": {"u_rel": self.angle_u_rel, "u_arcsec": self.angle_u_arcsec,
                          "u_interpolation_arcsec": self.interpolation_u_arcsec,
                          "signal_period_arcsec": self.signal_period_arcsec}}


def twist_arcsec(torque_nm: np.ndarray, reducer: Reducer) -> np.ndarray:
    """The true twist along a torque history (Dahl friction state carried through every sample)."""
    r = reducer
    spring = 60.0 * torque_nm / r.rigidity_nm_per_arcmin + 0.5 * r.play_arcsec * np.tanh(torque_nm / r.play_torque_nm)
    z = np.empty_like(torque_nm)
    state, half = 0.0, 0.5 * r.friction_width_arcsec
    z[0] = state
    d = np.diff(torque_nm)
    for i, step in enumerate(d, start=1):
        if step != 0.0:
            target = math.copysign(half, step)
            state = target + (state - target) * math.exp(-abs(step) / r.friction_torque_nm)
        z[i] = state
    return spring - z


def triangle(amplitude_nm: float, loops: int, rate_nm_per_s: float, sample_rate_hz: float, tip_dwell_s: float = 0.3
             ) -> tuple[np.ndarray, np.ndarray]:
    """0 → −T, then ``loops`` full loops −T → +T → −T, then back to 0, holding ``tip_dwell_s`` at each ±T (as a
    test profile does before reversing): time (s), torque (N·m)."""
    tips = [-amplitude_nm] + [amplitude_nm, -amplitude_nm] * loops
    waypoints, t_way = [0.0], [0.0]
    for tip in tips + [0.0]:
        t_way.append(t_way[-1] + abs(tip - waypoints[-1]) / rate_nm_per_s)
        waypoints.append(tip)
        if tip != 0.0 and tip_dwell_s > 0.0:
            t_way.append(t_way[-1] + tip_dwell_s)
            waypoints.append(tip)
    time_s = np.arange(0.0, t_way[-1], 1.0 / sample_rate_hz)
    return time_s, np.interp(time_s, t_way, waypoints)


def truth(reducer: Reducer, amplitude_nm: float, rated_nm: float, lost_motion_pct: float = 3.0,
          interval: tuple[float, float] = (0.5, 1.0)) -> dict[str, float]:
    """Rigidity (secant of the midline over the interval, both sides averaged), lost motion and backlash of the
    steady loop, from dense noise-free branches."""
    _, torque = triangle(amplitude_nm, 3, 1.0, 4000.0 / amplitude_nm * 100, tip_dwell_s=0.0)
    theta = twist_arcsec(torque, reducer)
    # the last full loop: the up branch from the last −T turning point to +T, then the down branch
    tips = np.flatnonzero(np.abs(np.abs(torque) - amplitude_nm) < 1e-9)
    neg = [i for i in tips if torque[i] < 0]
    pos = [i for i in tips if torque[i] > 0]
    a, b, c = neg[-2], pos[-1], neg[-1]
    up_t, up_a = torque[a:b + 1], theta[a:b + 1]
    dn_t, dn_a = torque[b:c + 1][::-1], theta[b:c + 1][::-1]

    def mid(level: float) -> float:
        return 0.5 * (np.interp(level, up_t, up_a) + np.interp(level, dn_t, dn_a))

    lo, hi = interval[0] * amplitude_nm, interval[1] * amplitude_nm
    k_pos = (hi - lo) / (mid(hi) - mid(lo))
    k_neg = (hi - lo) / (mid(-lo) - mid(-hi))
    level = lost_motion_pct / 100.0 * rated_nm
    return {"rigidity_nm_per_arcmin": 30.0 * (k_pos + k_neg),
            "lost_motion_arcsec": mid(level) - mid(-level),
            "backlash_arcsec": float(np.interp(0.0, dn_t, dn_a) - np.interp(0.0, up_t, up_a))}


def measure(reducer: Reducer, chain: Chain, rng: np.random.Generator, *, amplitude_nm: float = 1000.0,
            loops: int = 3, rate_nm_per_s: float = 500.0, sample_rate_hz: float = 100.0,
            torque_noise_nm: float = 0.2, angle_noise_arcsec: float = 0.05, drift_arcsec_per_s: float = 0.0
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One run: the readings with this run's systematic errors (drawn from ``chain``) and noise."""
    time_s, torque = triangle(amplitude_nm, loops, rate_nm_per_s, sample_rate_hz)
    theta = twist_arcsec(torque, reducer) + drift_arcsec_per_s * time_s
    phase = 2.0 * math.pi * theta / chain.signal_period_arcsec
    a, b = rng.normal(0.0, chain.interpolation_u_arcsec, 2)
    torque_read = (torque * (1.0 + rng.normal(0.0, chain.torque_u_rel)) + rng.normal(0.0, chain.torque_u_zero_nm)
                   + torque_noise_nm * rng.standard_normal(time_s.size))
    angle_read = (theta * (1.0 + rng.normal(0.0, chain.angle_u_rel)) + rng.normal(0.0, chain.angle_u_arcsec)
                  + a * np.sin(phase) + b * np.cos(phase) + angle_noise_arcsec * rng.standard_normal(time_s.size))
    return time_s, torque_read, angle_read

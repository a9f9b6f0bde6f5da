"""Synthetic hysteresis records with analytically known truth, for the analysis tests.

Model (angles in arcsec, torque in N·m, positive torque → positive twist):
    θ(T, d) = T/K + (L/2)·tanh(T/T_lm) + c3·T³ − d·h(T),   h(T) = (B/2)·(1 − (T/T_max)²)
d = +1 on B↑ (torque rising), −1 on B↓. K is the rigidity in N·m/arcsec, L the lost-motion zone, T_lm its
width, c3 an optional stiffening term, B the backlash (loop width at 0); the loop closes smoothly at ±T_max.
The midline is T/K + (L/2)·tanh(T/T_lm) + c3·T³, so every evaluated quantity has a closed form.
The profile is continuous at a constant torque rate: 0 → −T → +T → −T … → 0 (or mirrored).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest


@dataclass(frozen=True)
class LoopModel:
    rigidity_nm_per_arcmin: float = 294.0  # RV-110E catalogue central value
    rated_torque_nm: float = 1078.0
    test_torque_nm: float = 1078.0
    backlash_arcsec: float = 25.0
    lost_motion_zone_arcsec: float = 12.0
    lost_motion_zone_torque_nm: float = 20.0
    cubic_arcsec_per_nm3: float = 0.0

    @property
    def compliance_arcsec_per_nm(self) -> float:
        return 60.0 / self.rigidity_nm_per_arcmin

    def midline_arcsec(self, torque_nm):
        t = np.asarray(torque_nm, dtype=float)
        return (
            t * self.compliance_arcsec_per_nm
            + 0.5 * self.lost_motion_zone_arcsec * np.tanh(t / self.lost_motion_zone_torque_nm)
            + self.cubic_arcsec_per_nm3 * t**3
        )

    def angle_arcsec(self, torque_nm, direction):
        t = np.asarray(torque_nm, dtype=float)
        half_width = 0.5 * self.backlash_arcsec * (1.0 - (t / self.test_torque_nm) ** 2)
        return self.midline_arcsec(t) - direction * half_width

    def lost_motion_arcsec(self, pct: float = 3.0) -> float:
        level = pct / 100.0 * self.rated_torque_nm
        return float(self.midline_arcsec(level) - self.midline_arcsec(-level))

    def secant_rigidity_nm_per_arcmin(self, lo_nm: float, hi_nm: float) -> float:
        """Mean of the positive and negative side secants of the midline over |T| in [lo, hi]."""
        k_pos = (hi_nm - lo_nm) / (self.midline_arcsec(hi_nm) - self.midline_arcsec(lo_nm))
        k_neg = (hi_nm - lo_nm) / (self.midline_arcsec(-lo_nm) - self.midline_arcsec(-hi_nm))
        return float(30.0 * (k_pos + k_neg))


@dataclass(frozen=True)
class HarmonicDriveModel:
    """Harmonic Drive catalogue curve (three stiffness regions) as the midline, plus a closed hysteresis."""

    t1_nm: float = 29.0  # HFUC-32-100 (domain.md §2.2)
    t2_nm: float = 108.0
    k1_nm_per_rad: float = 6.7e4
    k2_nm_per_rad: float = 1.1e5
    k3_nm_per_rad: float = 1.2e5
    rated_torque_nm: float = 137.0  # assumption for the lost-motion level only
    test_torque_nm: float = 160.0
    backlash_arcsec: float = 20.0

    def midline_arcsec(self, torque_nm):
        return hd_model_angle(torque_nm, self.t1_nm, self.t2_nm, self.k1_nm_per_rad, self.k2_nm_per_rad,
                              self.k3_nm_per_rad)

    def angle_arcsec(self, torque_nm, direction):
        t = np.asarray(torque_nm, dtype=float)
        half_width = 0.5 * self.backlash_arcsec * (1.0 - (t / self.test_torque_nm) ** 2)
        return self.midline_arcsec(t) - direction * half_width


@dataclass
class Record:
    time_s: np.ndarray
    torque_nm: np.ndarray
    angle_arcsec: np.ndarray
    true_torque_nm: np.ndarray
    model: LoopModel
    rate_nm_per_s: float


def make_record(
    model: LoopModel | HarmonicDriveModel | None = None,
    *,
    loops: int = 3,
    conditioning_loops: int = 1,
    rate_nm_per_s: float = 100.0,
    sample_rate_hz: float = 500.0,
    torque_noise_nm: float = 0.0,
    angle_noise_arcsec: float = 0.0,
    first_sign: int = -1,
    seed: int = 0,
    angle_offset_arcsec: float = 3.7,
    time_offset_s: float = 12.5,
) -> Record:
    """A continuous test at a constant torque rate with the model's analytic twist and optional sensor noise."""
    model = model or LoopModel()
    amp = model.test_torque_nm
    n_loops = loops + conditioning_loops
    waypoints = [0.0] + [first_sign * amp * (-1) ** k for k in range(2 * n_loops + 1)] + [0.0]
    waypoints_t = np.concatenate(([0.0], np.cumsum(np.abs(np.diff(waypoints))) / rate_nm_per_s))
    time_s = np.arange(0.0, waypoints_t[-1], 1.0 / sample_rate_hz)
    true_torque = np.interp(time_s, waypoints_t, waypoints)
    segment = np.clip(np.searchsorted(waypoints_t, time_s, side="right") - 1, 0, len(waypoints) - 2)
    direction = np.sign(np.diff(waypoints))[segment]
    angle = model.angle_arcsec(true_torque, direction) + angle_offset_arcsec
    rng = np.random.default_rng(seed)
    torque = true_torque + torque_noise_nm * rng.standard_normal(time_s.size)
    angle = angle + angle_noise_arcsec * rng.standard_normal(time_s.size)
    return Record(time_s + time_offset_s, torque, angle, true_torque, model, rate_nm_per_s)


def make_stepped_record(
    model: LoopModel | None = None,
    *,
    loops: int = 2,
    step_nm: float = 49.0,
    dwell_s: float = 1.0,
    ramp_rate_nm_per_s: float = 500.0,
    sample_rate_hz: float = 200.0,
    torque_noise_nm: float = 0.0,
    angle_noise_arcsec: float = 0.0,
    seed: int = 0,
) -> Record:
    """Stepped profile: equal torque steps (ramped at ``ramp_rate``), each held for ``dwell_s``."""
    model = model or LoopModel()
    amp = model.test_torque_nm
    levels_up = np.arange(-amp, amp + step_nm / 2, step_nm)
    levels_up[-1] = amp
    one_loop = np.concatenate((levels_up, levels_up[::-1][1:]))
    lead_in = np.arange(0.0, -amp - step_nm / 2, -step_nm)[:-1]
    targets = np.concatenate((lead_in, np.tile(one_loop[:-1], loops), [-amp]))
    # Waypoints: hold each target for dwell_s, then ramp to the next.
    wp_torque = [0.0]
    wp_time = [0.0]
    for target in targets:
        wp_time.append(wp_time[-1] + abs(target - wp_torque[-1]) / ramp_rate_nm_per_s)
        wp_torque.append(target)
        wp_time.append(wp_time[-1] + dwell_s)
        wp_torque.append(target)
    wp_time_arr, wp_torque_arr = np.array(wp_time), np.array(wp_torque)
    time_s = np.arange(0.0, wp_time_arr[-1], 1.0 / sample_rate_hz)
    true_torque = np.interp(time_s, wp_time_arr, wp_torque_arr)
    # Direction = sign of the last nonzero ramp (holds keep the direction they arrived with).
    d = np.sign(np.diff(true_torque, prepend=true_torque[0]))
    nz = np.flatnonzero(d)
    direction = d[nz][np.clip(np.searchsorted(nz, np.arange(d.size), side="right") - 1, 0, None)]
    angle = model.angle_arcsec(true_torque, direction)
    rng = np.random.default_rng(seed)
    torque = true_torque + torque_noise_nm * rng.standard_normal(time_s.size)
    angle = angle + angle_noise_arcsec * rng.standard_normal(time_s.size)
    return Record(time_s, torque, angle, true_torque, model, float("nan"))


@pytest.fixture
def loop_model():
    return LoopModel


@pytest.fixture
def synth():
    return make_record


@pytest.fixture
def synth_stepped():
    return make_stepped_record


@pytest.fixture
def hd_model():
    return HarmonicDriveModel


@pytest.fixture
def rv110e_record():
    return make_record(LoopModel())


def hd_model_angle(torque_nm, t1, t2, k1, k2, k3):
    """Odd catalogue curve in arcsec (independent re-statement of the Harmonic Drive formula)."""
    t = np.abs(np.asarray(torque_nm, dtype=float))
    rad = np.where(
        t <= t1,
        t / k1,
        np.where(t <= t2, t1 / k1 + (t - t1) / k2, t1 / k1 + (t2 - t1) / k2 + (t - t2) / k3),
    )
    return np.sign(torque_nm) * rad * 180.0 * 3600.0 / math.pi


@pytest.fixture
def hd_angle():
    return hd_model_angle

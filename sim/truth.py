"""The truth of a test on the rich reducer model (``sim.reducer_model``), computed numerically.

The rich model's loop depends on the test itself (rate, dwells, position), so there is no closed form like
``sim.physics.loop_truth``. Here the noise-free forward model is run along the torque the drive applies for the
profile (its ramps and dwells through the drive's torque-loop lag, on the bench's sample grid, from a virgin
reducer) and every evaluated loop's branches are read at the levels of the definitions (DESIGN §2):
backlash = loop width at zero torque, lost motion = midline at +p·T_rated minus at −p·T_rated, rigidity = the
midline secant over [lo, hi]·T_test per side, averaged over both sides; each averaged over the evaluated loops.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from tcms_daq.sim.drive import TorqueDrive
from tcms_daq.sim.reducer_model import RichReducerModel

from tcms_daq.units import ARCSEC_PER_ARCMIN


def applied_torque_trace(segments: Sequence[Any], sample_rate_hz: float, time_constant_s: float
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(time s, applied torque N·m, loop index) of a profile's segments (``target_nm``, ``slope_nm_per_s``,
    ``dwell_s``, ``loop_index``) run by the drive model from zero torque, sampled at ``sample_rate_hz``."""
    drive = TorqueDrive(sample_rate_hz, time_constant_s)
    drive.set_enabled(True, 0.0)
    dt = 1.0 / sample_rate_hz
    times, torques, loops = [], [], []
    now, level, n = 0.0, 0.0, 0
    for seg in segments:
        drive.command(seg.target_nm, seg.slope_nm_per_s, now)
        end = now + abs(seg.target_nm - level) / seg.slope_nm_per_s + seg.dwell_s
        n_end = int(np.floor(end / dt + 1e-9))
        k = np.arange(n + 1, n_end + 1, dtype=float) * dt
        if k.size:
            _, applied = drive.step(k)
            times.append(k)
            torques.append(applied)
            loops.append(np.full(k.size, seg.loop_index))
        now, level, n = end, seg.target_nm, max(n, n_end)
    return np.concatenate(times), np.concatenate(torques), np.concatenate(loops)


def _branch_at(torque: np.ndarray, angle: np.ndarray, levels: np.ndarray, rising: bool) -> np.ndarray:
    """Angles of one monotonic branch at the torque levels (linear interpolation, ends held)."""
    order = np.argsort(torque, kind="stable") if rising else np.argsort(torque[::-1], kind="stable")
    t = torque[order] if rising else torque[::-1][order]
    a = angle[order] if rising else angle[::-1][order]
    return np.interp(levels, t, a)


def profile_truth(model: RichReducerModel, segments: Sequence[Any], position_deg: float, *, sample_rate_hz: float,
               time_constant_s: float, rated_torque_nm: float, lost_motion_pct: float = 3.0,
               rigidity_interval: tuple[float, float] = (0.5, 1.0)) -> dict[str, Any]:
    """Backlash, lost motion and rigidity (both sides) of the evaluated loops (loop index ≥ 1) of the test
    ``segments`` at output position ``position_deg``, averaged over the loops; keys as ``LoopTruth.to_dict``."""
    time_s, torque, loop = applied_torque_trace(segments, sample_rate_hz, time_constant_s)
    angle, _ = model.twist_arcsec(torque, time_s, position_deg)
    amplitude = max(abs(s.target_nm) for s in segments)
    p_t = lost_motion_pct / 100.0 * rated_torque_nm
    lo, hi = rigidity_interval[0] * amplitude, rigidity_interval[1] * amplitude
    levels = np.array([0.0, p_t, -p_t, lo, hi, -lo, -hi])
    rows = []
    dtorque = np.diff(torque, prepend=0.0)
    for index in sorted({int(i) for i in loop if i >= 1}):
        inside = loop == index
        up = inside & (dtorque > 0)
        down = inside & (dtorque < 0)
        if up.sum() < 2 or down.sum() < 2:
            continue
        rise = _branch_at(torque[up], angle[up], levels, rising=True)
        fall = _branch_at(torque[down], angle[down], levels, rising=False)
        mid = 0.5 * (rise + fall)
        k_pos = (hi - lo) / (mid[4] - mid[3]) * ARCSEC_PER_ARCMIN
        k_neg = (hi - lo) / (mid[5] - mid[6]) * ARCSEC_PER_ARCMIN
        rows.append((0.5 * (k_pos + k_neg), k_pos, k_neg, abs(fall[0] - rise[0]), mid[1] - mid[2]))
    if not rows:
        raise ValueError("the profile has no evaluated loop (loop index >= 1)")
    mean = np.mean(np.array(rows), axis=0)
    return {
        "test_torque_nm": float(amplitude),
        "rigidity_nm_per_arcmin": float(mean[0]),
        "rigidity_pos_nm_per_arcmin": float(mean[1]),
        "rigidity_neg_nm_per_arcmin": float(mean[2]),
        "backlash_arcsec": float(mean[3]),
        "lost_motion_arcsec": float(mean[4]),
        "lost_motion_torque_nm": float(p_t),
        "rigidity_interval": [float(rigidity_interval[0]), float(rigidity_interval[1])],
        "position_deg": float(position_deg),
        "model": "rich",
    }

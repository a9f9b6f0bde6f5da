"""The servo loader's torque path: CiA 402 profile-torque ramp (target + slope) and a first-order torque loop.

The ramp generator moves the torque demand from its present value towards the target at the commanded slope
(a step when the slope is None). The torque loop follows the demand with a first-order lag τ; the lag is
discretised exactly for a demand that is linear between samples (first-order hold), run with
``scipy.signal.lfilter`` over a whole batch with its state carried to the next one.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.signal import lfilter


class TorqueDrive:
    """Torque demand ramp + lagged applied torque, on the sample grid of the simulated clock (N·m, s)."""

    def __init__(self, sample_rate_hz: float, time_constant_s: float = 0.005, max_torque_nm: float = math.inf):
        if sample_rate_hz <= 0:
            raise ValueError(f"sample_rate_hz must be > 0 (got {sample_rate_hz})")
        if time_constant_s < 0:
            raise ValueError(f"time_constant_s must be >= 0 (got {time_constant_s})")
        self.max_torque_nm = float(max_torque_nm)
        self.enabled = False
        self.target_nm = 0.0
        self.slope_nm_per_s: float | None = None
        self._ramp_t0 = 0.0
        self._ramp_from_nm = 0.0
        dt = 1.0 / sample_rate_hz
        if time_constant_s == 0.0:
            self._b, self._a = np.array([1.0, 0.0]), np.array([1.0, 0.0])
        else:
            a = math.exp(-dt / time_constant_s)
            c = 1.0 + (time_constant_s / dt) * math.expm1(-dt / time_constant_s)  # 1 − (τ/dt)(1 − a)
            self._b, self._a = np.array([c, 1.0 - a - c]), np.array([1.0, -a])
        self._zi = np.zeros(1)
        self.applied_nm = 0.0

    def demand_at(self, time_s) -> np.ndarray:
        """Torque demand of the ramp generator at the given times (≥ the last command time)."""
        t = np.asarray(time_s, dtype=float)
        if not self.enabled:
            return np.zeros_like(t)
        span = self.target_nm - self._ramp_from_nm
        if self.slope_nm_per_s is None or span == 0.0:
            return np.full_like(t, self.target_nm)
        progress = np.clip((t - self._ramp_t0) * self.slope_nm_per_s, 0.0, abs(span))
        return self._ramp_from_nm + math.copysign(1.0, span) * progress

    def command(self, target_nm: float, slope_nm_per_s: float | None, now_s: float) -> None:
        """New target torque (clamped to ±max torque) and ramp slope (> 0, or None for a step)."""
        if not math.isfinite(target_nm):
            raise ValueError(f"target torque must be finite (got {target_nm})")
        if slope_nm_per_s is not None and not slope_nm_per_s > 0:
            raise ValueError(f"torque slope must be > 0 N·m/s (got {slope_nm_per_s})")
        if slope_nm_per_s is not None and math.isinf(slope_nm_per_s):
            slope_nm_per_s = None
        self._ramp_from_nm = float(self.demand_at(now_s)) if self.enabled else 0.0
        self._ramp_t0 = now_s
        self.target_nm = float(np.clip(target_nm, -self.max_torque_nm, self.max_torque_nm))
        self.slope_nm_per_s = slope_nm_per_s

    def set_enabled(self, enabled: bool, now_s: float) -> None:
        """Enable (the ramp starts from 0 N·m towards the stored target) or disable (demand 0 at once)."""
        if enabled and not self.enabled:
            self.enabled = True
            self._ramp_from_nm, self._ramp_t0 = 0.0, now_s
        elif not enabled:
            self.enabled = False
            self._ramp_from_nm, self._ramp_t0 = 0.0, now_s

    def demand_setpoint_nm(self, now_s: float) -> float:
        return float(self.demand_at(now_s))

    def step(self, time_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Advance the torque loop over consecutive sample times; returns (demand, applied torque) in N·m."""
        demand = self.demand_at(time_s)
        if demand.size == 0:
            return demand, demand.copy()
        applied, self._zi = lfilter(self._b, self._a, demand, zi=self._zi)
        self.applied_nm = float(applied[-1])
        return demand, applied

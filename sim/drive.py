"""The servo loader's torque path: CiA 402 profile-torque ramp (target + slope) and a first-order torque loop.

The ramp generator moves the torque demand from its present value towards the target at the commanded slope
(a step when the slope is None). The torque loop follows the demand with a first-order lag τ; the lag is
discretised exactly for a demand that is linear between samples (first-order hold):

    y[n] = a·y[n−1] + c·u[n] + (1 − a − c)·u[n−1],   a = e^{−dt/τ},   c = 1 − (τ/dt)·(1 − a)

evaluated over a whole batch in closed form (numpy, no per-sample loop; scipy.signal.lfilter would do the same
but costs a second of import time), with its state carried to the next batch.
"""

from __future__ import annotations

import math

import numpy as np

# Samples per closed-form chunk are limited so that e^{n·dt/τ} stays finite.
_MAX_DECAY = 500.0


def first_order_response(v: np.ndarray, a: float, y_prev: float, decay_per_sample: float) -> np.ndarray:
    """y[n] = a·y[n−1] + v[n] from y[−1] = y_prev, with a = e^{−decay_per_sample} (vectorised in chunks)."""
    out = np.empty(v.size)
    if a == 0.0:
        out[:] = v
        return out
    chunk = max(1, int(_MAX_DECAY / decay_per_sample))
    for start in range(0, v.size, chunk):
        seg = v[start : start + chunk]
        e = np.exp(decay_per_sample * np.arange(seg.size))  # a^{−i}
        out[start : start + seg.size] = (a * y_prev + np.cumsum(seg * e)) / e
        y_prev = float(out[start + seg.size - 1])
    return out


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
            self._decay, self._a, self._c = math.inf, 0.0, 1.0
        else:
            self._decay = dt / time_constant_s
            self._a = math.exp(-self._decay)
            self._c = 1.0 + math.expm1(-self._decay) / self._decay  # 1 − (τ/dt)(1 − a)
        self._demand_prev = 0.0
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
        previous = np.concatenate(([self._demand_prev], demand[:-1]))
        v = self._c * demand + (1.0 - self._a - self._c) * previous
        applied = first_order_response(v, self._a, self.applied_nm, self._decay)
        self._demand_prev = float(demand[-1])
        self.applied_nm = float(applied[-1])
        return demand, applied

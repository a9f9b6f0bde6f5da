"""A small, deterministic stand-in for :class:`sim.bench.SimulatedBench` for tests of the layers above the
physics (drivers, simulators, acquisition), which check protocols and plumbing rather than reducer physics.

``SpringBench`` has the same contract — ``set_drive_enabled``, ``set_torque_target(target_nm, slope_nm_per_s)``,
``advance(duration_s) -> Samples``, ``now_s`` — and a physics simple enough to predict by hand: the commanded
torque ramps at the slope, the applied torque follows it through a first-order lag, the output twists by
torque / rigidity plus a backlash step smoothed by ``tanh`` over ``backlash_width_nm``; seeded Gaussian noise
on both sensors and constant sensor offsets. Sign: positive torque twists positive. Sample ``k`` is at
``k / sample_rate_hz`` s; the clock moves by exactly the durations asked for.
"""

from __future__ import annotations

import math

import numpy as np

from tcms_daq.samples import Samples


class SpringBench:
    def __init__(
        self,
        *,
        rigidity_nm_per_arcmin: float = 300.0,
        backlash_arcsec: float = 0.0,
        backlash_width_nm: float = 20.0,
        lag_s: float = 0.01,
        sample_rate_hz: float = 1000.0,
        torque_noise_nm: float = 0.0,
        angle_noise_arcsec: float = 0.0,
        sensor_offset_nm: float = 0.0,
        angle_offset_arcsec: float = 0.0,
        seed: int = 0,
    ):
        self.rigidity_nm_per_arcmin = float(rigidity_nm_per_arcmin)
        self.backlash_arcsec = float(backlash_arcsec)
        self.backlash_width_nm = float(backlash_width_nm)
        self.lag_s = float(lag_s)
        self.sample_rate_hz = float(sample_rate_hz)
        self.torque_noise_nm = float(torque_noise_nm)
        self.angle_noise_arcsec = float(angle_noise_arcsec)
        self.sensor_offset_nm = float(sensor_offset_nm)
        self.angle_offset_arcsec = float(angle_offset_arcsec)
        self.rng = np.random.default_rng(seed)
        self._now_s = 0.0
        self._samples_made = 0  # sample k is at k / rate
        self.enabled = False
        self.target_nm = 0.0
        self.slope_nm_per_s = 1e9
        self.command_nm = 0.0
        self.applied_nm = 0.0

    @property
    def now_s(self) -> float:
        return self._now_s

    def set_drive_enabled(self, enabled: bool) -> None:
        self.enabled = enabled
        if not enabled:
            self.target_nm = 0.0
            self.command_nm = 0.0

    def set_torque_target(self, target_nm: float, slope_nm_per_s: float) -> None:
        self.target_nm = float(target_nm)
        self.slope_nm_per_s = float(slope_nm_per_s)

    def twist_arcsec(self, torque_nm: np.ndarray) -> np.ndarray:
        """True output twist (arcsec) at applied ``torque_nm``: spring plus the smoothed backlash step."""
        return (torque_nm / self.rigidity_nm_per_arcmin * 60.0
                + self.backlash_arcsec / 2.0 * np.tanh(torque_nm / self.backlash_width_nm))

    def advance(self, duration_s: float) -> Samples:
        self._now_s += duration_s
        end = int(math.floor(self._now_s * self.sample_rate_hz + 1e-9))
        n = max(end - self._samples_made, 0)
        dt = 1.0 / self.sample_rate_hz
        time_s = (self._samples_made + 1 + np.arange(n)) * dt
        applied = np.empty(n)
        step_nm = self.slope_nm_per_s * dt
        alpha = 1.0 - math.exp(-dt / self.lag_s)
        for i in range(n):  # a few samples per call in tests; the real simulator is vectorised
            if self.enabled:
                self.command_nm += min(step_nm, max(-step_nm, self.target_nm - self.command_nm))
            self.applied_nm += alpha * (self.command_nm - self.applied_nm)
            applied[i] = self.applied_nm
        self._samples_made += n
        true_angle = self.twist_arcsec(applied) + self.angle_offset_arcsec
        torque = applied + self.sensor_offset_nm + self.rng.normal(0.0, self.torque_noise_nm, n)
        angle = true_angle + self.rng.normal(0.0, self.angle_noise_arcsec, n)
        return Samples(time_s, torque, angle, {"applied_torque_nm": applied, "true_angle_arcsec": true_angle})

"""Fixtures of the driver tests: simulated instruments on ephemeral loopback ports over a small spring bench.

``SpringBench`` is a deterministic test double of ``sim.bench.SimulatedBench`` (same contract: profile-torque
ramp with a first-order torque loop, linear twist); the driver tests check protocols, not physics.
"""

from __future__ import annotations

import math
import uuid

import numpy as np
import pytest

from sim.instruments.physics import SharedPhysics
from sim.instruments.serve import InstrumentSimulators, SimulatorOptions
from tcms_daq.samples import Samples


class SpringBench:
    """Applied torque follows a ramped command with lag ``lag_s``; angle = torque / rigidity (+ offset)."""

    def __init__(self, rigidity_nm_per_arcsec: float = 5.0, lag_s: float = 0.01, sample_rate_hz: float = 1000.0,
                 sensor_offset_nm: float = 0.0, angle_offset_arcsec: float = 0.0):
        self.rigidity = rigidity_nm_per_arcsec
        self.lag_s = lag_s
        self.dt = 1.0 / sample_rate_hz
        self.sensor_offset_nm = sensor_offset_nm
        self.angle_offset_arcsec = angle_offset_arcsec
        self.now_s = 0.0
        self.enabled = False
        self.target_nm = 0.0
        self.slope = 1e9
        self.command_nm = 0.0
        self.applied_nm = 0.0
        self._carry = 0.0

    def set_drive_enabled(self, enabled: bool) -> None:
        self.enabled = enabled
        if not enabled:
            self.command_nm = 0.0

    def set_torque_target(self, target_nm: float, slope_nm_per_s: float) -> None:
        self.target_nm = target_nm
        self.slope = slope_nm_per_s

    def advance(self, duration_s: float) -> Samples:
        total = duration_s + self._carry
        n = int(total / self.dt)
        self._carry = total - n * self.dt
        t, tq, ang = np.empty(n), np.empty(n), np.empty(n)
        alpha = 1.0 - math.exp(-self.dt / self.lag_s)
        for i in range(n):
            if self.enabled:
                step = self.slope * self.dt
                self.command_nm += max(-step, min(step, self.target_nm - self.command_nm))
            self.applied_nm += alpha * (self.command_nm - self.applied_nm)
            self.now_s += self.dt
            t[i], tq[i] = self.now_s, self.applied_nm
            ang[i] = self.applied_nm / self.rigidity + self.angle_offset_arcsec
        return Samples(t, tq + self.sensor_offset_nm, ang,
                       extra={"applied_torque_nm": tq.copy(), "true_angle_arcsec": ang.copy()})


@pytest.fixture
def spring_physics():
    physics = SharedPhysics(SpringBench())
    yield physics
    physics.stop()


def _sims(physics, **options):
    opts = SimulatorOptions.from_mapping(
        {"ports": {"nd287": 0, "aed": 0, "modbus": 0, "socketcand": 0}}, **options
    )
    sims = InstrumentSimulators(physics, opts)
    sims.start()
    return sims


@pytest.fixture
def serial_sims(spring_physics):
    """ND 287 + AED simulators on ephemeral ports (physics stepped by hand)."""
    sims = _sims(spring_physics, instruments=("nd287", "aed"))
    yield sims
    sims.stop()


@pytest.fixture
def make_sims(spring_physics):
    """Factory: simulators with options (ephemeral ports, unique CAN channel); all stopped at teardown."""
    started = []

    def make(**options):
        options.setdefault("can_channel", f"t-{uuid.uuid4().hex[:10]}")
        options.setdefault("can_interface", "virtual")
        sims = _sims(spring_physics, **options)
        started.append(sims)
        return sims

    yield make
    for sims in started:
        sims.stop()

"""Fixtures of the driver tests: simulated instruments on ephemeral loopback ports over the shared spring
double (``sim.testing.SpringBench``, noiseless, no backlash); the driver tests check protocols, not physics."""

from __future__ import annotations

import uuid

import pytest
from tcms_daq.sim.instruments.physics import SharedPhysics
from tcms_daq.sim.instruments.serve import DEFAULT_PORTS, InstrumentSimulators, SimulatorOptions
from tcms_daq.sim.testing import SpringBench


@pytest.fixture
def spring_physics():
    physics = SharedPhysics(SpringBench())
    yield physics
    physics.stop()


def _sims(physics, **options):
    opts = SimulatorOptions.from_mapping(
        {"ports": dict.fromkeys(DEFAULT_PORTS, 0)}, **options
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

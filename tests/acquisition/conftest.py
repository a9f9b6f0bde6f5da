"""Fixtures for the acquisition tests: virtual benches on the shared spring double (``sim.testing``), protocol
benches, and a short GB-style profile."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
from tcms_daq.sim.testing import SpringBench

from tcms_daq.acquisition import compose_bench
from tcms_daq.config import BenchConfig
from tcms_daq.procedure.profiles import continuous_profile

RIGIDITY_NM_PER_ARCMIN = 300.0
BACKLASH_ARCSEC = 10.0


def spring_with_backlash(seed: int = 0, rate_hz: float = 1000.0, tau_s: float = 0.005, torque_noise_nm: float = 0.2,
                  angle_noise_arcsec: float = 0.1) -> SpringBench:
    """The acquisition tests' bench: the shared spring double with backlash and seeded sensor noise."""
    return SpringBench(rigidity_nm_per_arcmin=RIGIDITY_NM_PER_ARCMIN, backlash_arcsec=BACKLASH_ARCSEC,
                       lag_s=tau_s, sample_rate_hz=rate_hz, torque_noise_nm=torque_noise_nm,
                       angle_noise_arcsec=angle_noise_arcsec, seed=seed)


def virtual_config(max_torque_nm: float = 2000.0) -> BenchConfig:
    inst = {"driver": "virtual", "url": "virtual://sim"}
    return BenchConfig.model_validate({"bench": {"name": "test bench", "max_torque_nm": max_torque_nm},
                                       "instruments": {"angle": inst, "torque": inst, "loader": inst}})


@pytest.fixture
def make_bench():
    def make(seed: int = 0, max_torque_nm: float = 2000.0, speed: float | None = None, **physics_kw):
        """speed: None runs the simulated clock as fast as possible (stepped); a number paces it (threads)."""
        return compose_bench(virtual_config(max_torque_nm), speed=speed,
                             physics_factory=lambda _cfg: spring_with_backlash(seed, **physics_kw))

    return make


def gb_profile(peak_nm: float = 300.0, slope_nm_per_s: float = 600.0, cycles: int = 1):
    """The core's GB-style continuous profile: 0 → −T, a conditioning loop, ``cycles`` evaluated loops, → 0."""
    return continuous_profile(peak_nm, slope_nm_per_s, cycles=cycles, conditioning_loops=1, tip_dwell_s=0.05)


@pytest.fixture
def profile():
    return gb_profile()


@pytest.fixture
def make_profile():
    return gb_profile


LOOPBACK_MODBUS = Path(__file__).resolve().parents[2] / "config" / "bench-loopback-modbus.toml"


class ProtocolBench:
    """The loopback bench's instruments as protocol simulators in this process (ND 287, AED, Modbus drive) on
    one SimulatedBench ticking at real time × speed, and the bench config pointing at their ephemeral ports."""

    def __init__(self, speed: float, comm_timeout_s: float = 0.0):
        from tcms_daq.sim.bench import SimulatedBench
        from tcms_daq.sim.instruments.physics import SharedPhysics
        from tcms_daq.sim.instruments.serve import InstrumentSimulators, SimulatorOptions

        from tcms_daq.config import load_bench_config

        self.speed = speed
        self.config = load_bench_config(LOOPBACK_MODBUS)
        self.physics = SharedPhysics(SimulatedBench.from_config(self.config))  # as `tcms sim serve` builds it
        opts = SimulatorOptions(ports={"nd287": 0, "aed": 0, "modbus": 0}, instruments=("nd287", "aed", "modbus"),
                                modbus_comm_timeout_s=comm_timeout_s)
        self.sims = InstrumentSimulators(self.physics, opts)
        self.ports = self.sims.start()
        self.physics.start(speed)

    def bench_config(self) -> BenchConfig:
        inst = self.config.instruments
        urls = {"angle": f"socket://127.0.0.1:{self.ports['nd287']}", "torque": f"socket://127.0.0.1:{self.ports['aed']}",
                "loader": f"tcp://127.0.0.1:{self.ports['modbus']}"}
        instruments = inst.model_copy(update={k: getattr(inst, k).model_copy(
                                              update={"options": getattr(inst, k).options.model_copy(update={"url": url})})
                                              for k, url in urls.items()})
        return self.config.model_copy(update={"instruments": instruments})

    def compose(self):
        return compose_bench(self.bench_config(), config_dir=LOOPBACK_MODBUS.parent, speed=self.speed)

    def stop(self) -> None:
        self.physics.stop()
        self.sims.stop()


@pytest.fixture
def protocol_bench():
    made = []

    def make(speed: float = 4.0, comm_timeout_s: float = 0.0) -> ProtocolBench:
        pb = ProtocolBench(speed, comm_timeout_s)
        made.append(pb)
        return pb

    yield make
    for pb in made:
        pb.stop()


@pytest.fixture
def make_spring():
    """The stand-in physics class (for tests composing their own config)."""
    return spring_with_backlash


@pytest.fixture
def break_compensation_once():
    """``break_(bench, at_call)``: the bench's compensation raises FloatingPointError("compensation blew up")
    on its ``at_call``-th batch, once (a bug in the acquisition path)."""

    def break_(bench, at_call: int) -> None:
        real_compensate = bench.compensate
        calls = {"n": 0}

        def flaky(raw, torque, t):
            calls["n"] += 1
            if calls["n"] == at_call:
                raise FloatingPointError("compensation blew up")
            return real_compensate(raw, torque, t)

        bench.compensate = flaky

    return break_


#: two independent results agree when their difference is within this many times their expanded uncertainties
#: combined. At 1 a correct 95 % U fails one comparison in twenty, and these tests make several per run (four in
#: the protocol end-to-end test: one suite run in five would fail with an exact U); 1.5 is about three standard
#: uncertainties of the difference. Whether U covers at 95 % is proven statistically in tests/uncertainty.
AGREEMENT_FACTOR = 1.5


@pytest.fixture
def agree_within_u():
    def check(result: dict, reference: dict, key: str) -> None:
        """|result − reference| within AGREEMENT_FACTOR × the two runs' U combined (a difference of two independent
        measurements), not a fixed share: a loaded machine samples more coarsely and says so in U."""
        u = result["uncertainty"][key]["U"], reference["uncertainty"][key]["U"]
        allowed = AGREEMENT_FACTOR * math.hypot(*u)
        assert abs(result[key] - reference[key]) <= allowed, (key, result[key], reference[key], u)

    return check

"""Bench composition from config, the clocks, and the virtual drivers' contracts."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
from tcms_daq.drivers.base import CommandRejected, DeviceFault, Disconnected
from tcms_daq.sim.virtual import VirtualBench, VirtualLoader, parse_virtual_url

from tcms_daq.acquisition import MonotonicClock, SimulatedClock, compose_bench
from tcms_daq.acquisition.bench import read_bench_config
from tcms_daq.config import BenchConfig
from tcms_daq.config.loader import validate
from tcms_daq.errors import ConfigError

VIRTUAL = {"driver": "virtual", "url": "virtual://sim"}


def config(**instruments) -> BenchConfig:
    inst = {"angle": dict(VIRTUAL), "torque": dict(VIRTUAL), "loader": dict(VIRTUAL)}
    inst.update(instruments)
    return validate(BenchConfig, {"bench": {"name": "b", "max_torque_nm": 500.0}, "instruments": inst}, "<test>")


def test_virtual_instruments_share_one_bench_and_its_simulated_clock(make_spring):
    bench = compose_bench(config(), physics_factory=lambda _c: make_spring())
    assert isinstance(bench.clock, SimulatedClock) and bench.clock.stepped
    assert bench.angle.bench is bench.torque.bench is bench.loader.bench
    assert bench.loader.max_torque_nm == 500.0  # the bench limit when the loader names none
    bench.connect()
    bench.clock.sleep(0.25)
    a, t = bench.angle.read(), bench.torque.read()
    assert len(a) == len(t) == 250 and bench.clock.now() == pytest.approx(0.25)
    np.testing.assert_array_equal(a.time_s, t.time_s)
    assert len(bench.angle.read()) == 0  # drained
    bench.close()


def test_composition_errors_are_one_line(make_spring):
    # the options are checked when the config is validated, before anything is composed
    with pytest.raises(ConfigError, match="instruments.angle: unknown driver 'nd999'"):
        config(angle={"driver": "nd999", "url": "x"})
    with pytest.raises(ConfigError, match=r"instruments.loader: driver 'virtual' has no option 'gain' \(its options: "):
        config(loader={**VIRTUAL, "gain": 2.0})  # an option the driver does not take
    with pytest.raises(ConfigError, match="cannot mix simulated"):
        compose_bench(config(angle={"driver": "nd287", "url": "socket://127.0.0.1:1"}),
                      physics_factory=lambda _c: make_spring())
    with pytest.raises(ConfigError, match="share one bench"):
        compose_bench(config(angle={"driver": "virtual", "url": "virtual://other"}),
                      physics_factory=lambda _c: make_spring())
    with pytest.raises(ConfigError, match="virtual://sim"):
        parse_virtual_url("socket://127.0.0.1:4001")
    with pytest.raises(ConfigError, match="no such file"):
        read_bench_config("/nonexistent/bench.toml")


def test_real_instruments_get_the_bench_clock():
    bench = compose_bench(config(angle={"driver": "nd287", "url": "socket://127.0.0.1:1"},
                                 torque={"driver": "aed", "url": "socket://127.0.0.1:1"},
                                 loader={"driver": "cia402-modbus", "url": "tcp://127.0.0.1:1"}), speed=8.0)
    assert isinstance(bench.clock, MonotonicClock) and bench.clock.speed == 8.0
    assert bench.angle.clock == bench.clock.now and bench.torque.clock == bench.clock.now
    before = time.monotonic() * 8.0
    stamp = bench.angle.clock()
    assert before <= stamp <= time.monotonic() * 8.0  # bracketed: no tolerance a preemption could exceed


def test_simulated_clock_runs_free_or_paced(make_spring, monkeypatch):
    vb = VirtualBench(make_spring())
    real_sleep = time.sleep
    slept: list[float] = []
    monkeypatch.setattr(time, "sleep", lambda s: (slept.append(s), real_sleep(s)))
    free = SimulatedClock(vb)
    free.sleep(5.0)
    assert vb.now_s() == pytest.approx(5.0) and slept == []  # free-running: never waits for the wall clock
    paced = SimulatedClock(vb, speed=20.0)
    paced.sleep(1.0)  # 1 s simulated at 20× real time: 50 ms of real waiting
    assert vb.now_s() == pytest.approx(6.0) and sum(slept) == pytest.approx(0.05, abs=0.01)
    with pytest.raises(ValueError):
        SimulatedClock(vb, speed=0)
    with pytest.raises(ValueError):
        MonotonicClock(speed=math.inf)


def test_virtual_loader_validates_before_touching_the_physics(make_spring):
    vb = VirtualBench(make_spring())
    loader = VirtualLoader(vb, rated_torque_nm=300.0)
    loader.connect()
    with pytest.raises(CommandRejected, match="not in OPERATION ENABLED"):
        loader.set_torque(100.0, 50.0)
    loader.enable()
    with pytest.raises(CommandRejected, match="outside ±300"):
        loader.set_torque(301.0, 50.0)
    with pytest.raises(CommandRejected, match="slope"):
        loader.set_torque(100.0, -1.0)
    assert vb.physics.target_nm == 0.0  # nothing reached the drive
    vb.inject_drive_fault(0x2310)
    status = loader.status()
    assert status.fault and status.state == "FAULT" and status.error_code == 0x2310
    with pytest.raises(DeviceFault):
        loader.enable()
    loader.fault_reset()
    loader.enable()
    assert loader.status().state == "OPERATION ENABLED"
    vb.lose_loader_link()
    with pytest.raises(Disconnected):
        loader.status()


def test_virtual_fault_hooks_fire_at_their_simulated_time(make_spring):
    vb = VirtualBench(make_spring())
    fired = []
    vb.at(0.1234, lambda: fired.append(vb.now_s()))
    vb.advance(0.5)
    assert fired == [pytest.approx(0.123, abs=0.0011)]


def test_a_paced_simulated_clock_steps_by_real_time_and_waits_for_conditions_finely(make_bench, monkeypatch):
    """The step grows with the speed (about 50 steps per real second: the cost follows real time) and is
    stated in both times; a wait for a condition still checks it at the configured step."""
    from tcms_daq.acquisition import AcquisitionLoop
    from tcms_daq.acquisition.loop import REAL_STEP_S

    free = AcquisitionLoop(make_bench())
    assert free.period_s == 0.02 and free.step_real_s is None
    bench = make_bench(speed=100.0)
    acq = AcquisitionLoop(bench)
    assert acq.period_s == pytest.approx(100.0 * REAL_STEP_S) and acq.step_real_s == pytest.approx(REAL_STEP_S)
    passed: list[float] = []
    monkeypatch.setattr(acq.scheduler, "pass_time", lambda loop, now, dt: (passed.append(dt), bench.clock.sleep(dt)))
    acq.wait(5.0, check_trips=False)
    assert passed == pytest.approx([2.0, 2.0, 1.0])
    passed.clear()
    start = bench.clock.now()
    assert acq.wait(5.0, check_trips=False, until=lambda: bench.clock.now() >= start + 0.1)
    assert passed and max(passed) == pytest.approx(0.02)


def test_virtual_instruments_on_the_real_time_clock_run_on_the_threaded_scheduler(make_spring, profile):
    # virtual://sim?clock=real-time: the physics follows the bench's real-time clock (here at 20× real time), the
    # drivers look like real instruments (no simulated time source), so the acquisition reads them in threads
    from tcms_daq.acquisition import AcquisitionLoop, TestRun
    from tcms_daq.acquisition.schedulers import ThreadedScheduler

    real_time = {"driver": "virtual", "url": "virtual://sim?clock=real-time"}
    bench = compose_bench(config(angle=real_time, torque=real_time, loader=real_time), speed=20.0,
                          physics_factory=lambda _c: make_spring())
    assert isinstance(bench.clock, MonotonicClock) and not bench.clock.stepped
    assert bench.angle.time_source is None and bench.angle.bench.real_time
    assert isinstance(AcquisitionLoop(bench).scheduler, ThreadedScheduler)
    started_s = bench.clock.now()
    record = TestRun(bench, profile).run()  # ±300 N·m
    assert record.state == "completed", record.reason
    s = record.samples
    # stamped on the bench clock, at the simulated sample rate, from the run's own time on
    assert started_s <= s.time_s[0] and s.time_s[-1] <= bench.clock.now()
    np.testing.assert_allclose(np.diff(s.time_s), 1e-3, rtol=1e-6)
    # the spring's compliance (300 N·m/arcmin) on each side, where its backlash term is saturated
    for sign in (1, -1):
        sel = (sign * s.torque_nm > 150.0) & (sign * s.torque_nm < 285.0)
        slope_arcsec_per_nm = np.polyfit(s.torque_nm[sel], s.angle_arcsec[sel], 1)[0]
        assert 60.0 / slope_arcsec_per_nm == pytest.approx(300.0, rel=0.02)


def test_the_instruments_of_one_virtual_bench_share_its_clock(make_spring):
    real_time = {"driver": "virtual", "url": "virtual://sim?clock=real-time"}
    with pytest.raises(ConfigError, match="one clock"):
        compose_bench(config(angle=real_time), physics_factory=lambda _c: make_spring())
    with pytest.raises(ConfigError, match=r"\?clock=simulated or \?clock=real-time"):
        compose_bench(config(angle={"driver": "virtual", "url": "virtual://sim?clock=fast"}),
                      physics_factory=lambda _c: make_spring())

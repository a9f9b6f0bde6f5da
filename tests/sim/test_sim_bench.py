"""The simulated bench: clock, drive ramp + lag, sensors, hooks, determinism under a seed."""

from __future__ import annotations

import math

import numpy as np
import pytest
from tcms_daq.sim.bench import SimulatedBench
from tcms_daq.sim.physics import ReducerPhysics, physics_from_spec

from tcms_daq.config import SimConfig
from tcms_daq.errors import ConfigError
from tcms_daq.samples import Samples

QUIET = dict(torque_noise_nm=0.0, encoder_noise_arcsec=0.0, encoder_resolution_arcsec=0.0)


def _drive(bench: SimulatedBench, first: list[float], second: list[float]) -> Samples:
    bench.set_drive_enabled(True)
    bench.set_torque_target(-800.0, 400.0)
    parts = [bench.advance(d) for d in first]
    bench.set_torque_target(600.0, 300.0)
    parts += [bench.advance(d) for d in second]
    return Samples.concat(parts)


def test_same_seed_same_samples_and_batching_does_not_matter(catalogue):
    spec = catalogue["RV-110E"]
    a = _drive(SimulatedBench(physics_from_spec(spec), reducer=spec, seed=7), [3.0], [4.0])
    b = _drive(SimulatedBench(physics_from_spec(spec), reducer=spec, seed=7), [0.25] * 12, [0.5] * 8)
    assert len(a) == len(b) == 3500
    for name, col in a.columns().items():
        np.testing.assert_allclose(col, b.columns()[name], rtol=0, atol=1e-9, err_msg=name)
    c = _drive(SimulatedBench(physics_from_spec(spec), reducer=spec, seed=8), [3.0], [4.0])
    assert not np.allclose(a.torque_nm, c.torque_nm)
    np.testing.assert_allclose(a.extra["applied_torque_nm"], c.extra["applied_torque_nm"])  # noise only differs


def test_clock_and_sample_times():
    bench = SimulatedBench(ReducerPhysics(), sample_rate_hz=200.0, **QUIET)
    assert bench.now_s == 0.0
    s1 = bench.advance(0.0123)  # 2 samples (5 ms, 10 ms)
    s2 = bench.advance(0.0077)  # up to 20 ms: 2 more
    assert list(np.round(np.concatenate([s1.time_s, s2.time_s]), 9)) == [0.005, 0.01, 0.015, 0.02]
    assert bench.now_s == pytest.approx(0.02)
    assert len(bench.advance(100.0)) == 20000  # simulated clock: 100 s at once
    with pytest.raises(ValueError):
        bench.advance(-1.0)


def test_profile_ramp_and_first_order_lag_are_exact():
    tau, fs, slope = 0.01, 1000.0, 500.0
    bench = SimulatedBench(ReducerPhysics(), sample_rate_hz=fs, torque_loop_time_constant_s=tau, **QUIET)
    bench.set_drive_enabled(True)
    bench.set_torque_target(1000.0, slope)
    s = bench.advance(1.0)
    t = s.time_s
    demand = s.extra["demand_nm"]
    np.testing.assert_allclose(demand, np.minimum(slope * t, 1000.0), atol=1e-9)
    ramp = t <= 2.0 - 1e-9
    # ramp through a first-order lag: y = slope·(t − τ(1 − e^{−t/τ}))
    expected = slope * (t - tau * (1 - np.exp(-t / tau)))
    np.testing.assert_allclose(s.extra["applied_torque_nm"][ramp], expected[ramp], rtol=1e-9, atol=1e-9)
    s2 = bench.advance(2.0)  # ramp ends at t = 2 s, the lag settles on the target
    assert s2.extra["applied_torque_nm"][-1] == pytest.approx(1000.0, abs=1e-6)
    bench.set_drive_enabled(False)
    s3 = bench.advance(0.2)
    assert abs(s3.extra["applied_torque_nm"][-1]) == pytest.approx(1000.0 * math.exp(-0.2 / tau), rel=0.1)  # a step is a one-sample ramp (FOH)
    assert bench.snapshot()["drive_enabled"] is False


def test_target_is_clamped_and_commands_validated():
    bench = SimulatedBench(ReducerPhysics(), max_torque_nm=500.0, torque_loop_time_constant_s=0.0, **QUIET)
    bench.set_drive_enabled(True)
    bench.set_torque_target(900.0)  # step
    s = bench.advance(0.1)
    assert s.extra["applied_torque_nm"].max() == pytest.approx(500.0)
    with pytest.raises(ValueError, match="slope"):
        bench.set_torque_target(100.0, -5.0)
    with pytest.raises(ValueError, match="finite"):
        bench.set_torque_target(math.nan)


def test_disabled_drive_applies_no_torque():
    bench = SimulatedBench(ReducerPhysics(), **QUIET)
    bench.set_torque_target(300.0, 1000.0)
    assert np.all(bench.advance(0.5).extra["applied_torque_nm"] == 0.0)
    bench.set_drive_enabled(True)  # the ramp starts from 0 at enable
    s = bench.advance(1.0)
    assert s.extra["demand_nm"][0] == pytest.approx(1000.0 * 0.002)
    assert s.extra["demand_nm"][-1] == pytest.approx(300.0)


def test_torque_sensor_gain_offset_tare_and_encoder_quantisation():
    params = ReducerPhysics(compliance_arcsec_per_nm=0.2)
    bench = SimulatedBench(params, torque_gain=1.01, torque_offset_nm=2.5, torque_noise_nm=0.0,
                           encoder_noise_arcsec=0.0, encoder_resolution_arcsec=0.5, torque_loop_time_constant_s=0.0)
    idle = bench.advance(0.1)
    np.testing.assert_allclose(idle.torque_nm, 2.5)
    assert bench.tare(0.1) == pytest.approx(2.5)
    bench.set_drive_enabled(True)
    bench.set_torque_target(100.0, None)
    s = bench.advance(0.1)
    np.testing.assert_allclose(s.torque_nm, 1.01 * s.extra["applied_torque_nm"])
    np.testing.assert_allclose(s.extra["true_angle_arcsec"], 20.0)
    np.testing.assert_allclose(s.angle_arcsec, 20.0)  # 20.0 is on the 0.5″ grid
    assert np.all(np.isclose(np.mod(s.angle_arcsec, 0.5), 0.0) | np.isclose(np.mod(s.angle_arcsec, 0.5), 0.5))


def test_noise_levels(catalogue):
    bench = SimulatedBench(physics_from_spec(catalogue["RV-110E"]), torque_noise_nm=0.5, encoder_noise_arcsec=0.2,
                           encoder_resolution_arcsec=0.0, seed=3)
    s = bench.advance(20.0)
    assert np.std(s.torque_nm - s.extra["applied_torque_nm"]) == pytest.approx(0.5, rel=0.05)
    assert np.std(s.angle_arcsec - s.extra["true_angle_arcsec"]) == pytest.approx(0.2, rel=0.05)


def test_measuring_chain_and_effects_hooks():
    calls = []

    def chain(true_angle, torque, time_s):
        calls.append(len(true_angle))
        return 1.01 * true_angle + 0.001 * torque

    def effects(cols):
        cols["torque_signal_nm"] = cols["torque_signal_nm"] + 1.0  # a torque offset the model does not know
        cols["angle_signal_arcsec"] = cols["angle_signal_arcsec"] + 0.5 * cols["time_s"]  # a drift

    bench = SimulatedBench(ReducerPhysics(compliance_arcsec_per_nm=0.2), measuring_chain=chain, effects=effects,
                           torque_loop_time_constant_s=0.0, **QUIET)
    bench.set_drive_enabled(True)
    bench.set_torque_target(100.0, None)
    s = bench.advance(1.0)
    assert calls == [500]
    np.testing.assert_allclose(s.extra["true_angle_arcsec"], 20.0)
    # the effects act on the reducer's angle, the chain reads it: the drift comes through the chain's scale
    np.testing.assert_allclose(s.angle_arcsec, 1.01 * (20.0 + 0.5 * s.time_s) + 0.1)
    np.testing.assert_allclose(s.torque_nm, 101.0)


def test_built_from_config(bench_config, catalogue, write, bench_text):
    bench = SimulatedBench(bench_config)  # what sim/virtual.py does with the whole config
    assert bench.reducer.name == "RV-110E" and bench.sample_rate_hz == 500.0 and bench.max_torque_nm == 2000.0
    assert SimulatedBench().reducer.name == "RV-110E"
    b2 = SimulatedBench(SimConfig(reducer="RV-60N", seed=4))
    assert b2.reducer.name == "RV-60N" and b2.seed == 4
    b3 = SimulatedBench.from_config(bench_config, catalogue["HFUC-32-100"], seed=9)
    assert b3.physics.hd_breakpoints_nm == (29.0, 108.0) and b3.seed == 9
    with pytest.raises(ConfigError, match="unknown reducer 'XYZ'"):
        SimulatedBench(SimConfig(reducer="XYZ"))


def test_truth_and_snapshot(catalogue):
    spec = catalogue["RV-110E"]
    bench = SimulatedBench(physics_from_spec(spec), reducer=spec)
    assert bench.truth().rigidity_nm_per_arcmin == pytest.approx(294.0)
    assert bench.truth(539.0).rigidity_nm_per_arcmin > 294.0  # the secant depends on the amplitude
    snap = bench.snapshot()
    assert snap["reducer"] == "RV-110E" and snap["now_s"] == 0.0 and "last" in snap


def test_effects_table_is_built_by_sim_effects(write, bench_text):
    from tcms_daq.config import load_bench_config

    bench_text = "\n".join(ln for ln in bench_text.splitlines() if not ln.startswith("geometry ="))

    on = bench_text.replace("[sim.effects]", "[sim.effects.time_skew]\nskew_s = 0.004\n", 1)
    bench = SimulatedBench(load_bench_config(write("on.toml", on)))
    assert bench.effects is not None
    bad = bench_text.replace("[sim.effects]", "[sim.effects.warp_drive]\nfactor = 9\n", 1)
    path = write("bad.toml", bad)
    with pytest.raises(ConfigError) as exc:
        SimulatedBench(load_bench_config(path))
    assert str(path) in str(exc.value) and "warp_drive" in str(exc.value)


def test_first_order_response_matches_the_recurrence_over_many_chunks():
    from tcms_daq.sim.drive import first_order_response

    rng = np.random.default_rng(0)
    v = rng.normal(size=3000)
    decay = 0.7  # chunks of 714 samples
    a = math.exp(-decay)
    expected, y = np.empty_like(v), 2.0
    for i, x in enumerate(v):
        y = a * y + x
        expected[i] = y
    np.testing.assert_allclose(first_order_response(v, a, 2.0, decay), expected, rtol=1e-10, atol=1e-10)


def test_sim_geometry_gives_the_measuring_chain(bench_config):
    """[sim] geometry: the encoder reads through the chain's errors (the compensator's forward model)."""
    assert bench_config.sim.geometry
    bench = SimulatedBench(bench_config)
    identity = SimulatedBench(bench_config, measuring_chain=lambda angle, torque, time_s: angle)
    for b in (bench, identity):
        b.set_drive_enabled(True)
        b.set_torque_target(1000.0, None)
    s, s0 = bench.advance(1.0), identity.advance(1.0)
    np.testing.assert_allclose(s.extra["true_angle_arcsec"], s0.extra["true_angle_arcsec"])
    assert abs(np.mean(s.angle_arcsec - s0.angle_arcsec)) > 1.0  # the chain's error at 1000 N·m


def test_missing_geometry_file_is_a_config_error(write, bench_text):
    from tcms_daq.config import load_bench_config

    path = write("bench.toml", bench_text)  # names geometry-sim.toml, which is not next to this copy
    with pytest.raises(ConfigError, match="geometry-sim.toml"):
        SimulatedBench(load_bench_config(path))

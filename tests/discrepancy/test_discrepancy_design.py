"""Derived signals and input checks of the discrepancy workflow."""

from __future__ import annotations

import numpy as np
import pytest
from tcms_daq.sim.effects import HiddenEffects, effects_from_table, effects_to_table, from_config

from tcms_daq.discrepancy.catalogue import separating_experiment
from tcms_daq.discrepancy.design import build_design, load_direction, loop_groups
from tcms_daq.errors import ConfigError, DataFormatError
from tcms_daq.samples import Samples


def triangle(n_loops=4, n_per_half=200, amp=500.0, noise=2.0, seed=0):
    up = np.linspace(-amp, amp, n_per_half, endpoint=False)
    dn = np.linspace(amp, -amp, n_per_half, endpoint=False)
    t = np.concatenate([np.concatenate((up, dn)) for _ in range(n_loops)])
    return t + noise * np.random.default_rng(seed).standard_normal(len(t))


def test_load_direction_ignores_noise_and_finds_reversals():
    torque = triangle()
    d = load_direction(torque)
    assert set(np.unique(d)) == {-1, 1}
    flips = np.count_nonzero(np.diff(d) != 0)
    assert flips == 7  # 4 loops: up, down × 4 → 7 reversals
    assert d[50] == 1 and d[250] == -1


def test_a_hold_at_the_tip_stays_on_the_branch_it_ends():
    """The reducer turns when the torque moves back, not at the hold's highest noise reading: measured from that
    reading, one a noise sigma low had left the tip already, and a 0.2 s hold at 50 Hz (the service's tip hold)
    turned up to 9 rows early — a hidden 2″ backlash then stood 2″ off on those rows."""
    early = []
    for seed in range(40):
        rng = np.random.default_rng(seed)
        ramp = np.arange(-600.0, 600.0, 12.0)  # 600 N·m/s at 50 Hz
        torque = np.concatenate((ramp, np.full(10, 600.0), ramp[::-1], np.full(10, -600.0), ramp))
        torque = torque + rng.normal(0.0, 0.3, len(torque))
        turns = np.flatnonzero(np.diff(load_direction(torque))) + 1
        early.append([len(ramp) + 10 - int(turns[0]), 2 * len(ramp) + 21 - int(turns[1])])  # ramp[0] is a hold row
    assert np.all(np.array(early) == 0), early


def test_loops_between_torque_minima():
    torque = triangle(n_loops=5)
    d = load_direction(torque)
    groups = loop_groups(d, np.zeros(len(torque), dtype=int))
    assert groups.max() + 1 == 5


def _pair(n=400):
    torque = triangle(n_loops=2, n_per_half=n // 4)
    t = np.arange(len(torque)) * 0.01
    return Samples(t, torque, 0.2 * torque), Samples(t, torque, 0.2 * torque)


def test_misaligned_files_are_rejected_with_one_line():
    m, s = _pair()
    s2 = Samples(s.time_s, s.torque_nm + np.where(np.arange(len(s)) == 17, 5.0, 0.0), s.angle_arcsec)
    with pytest.raises(DataFormatError, match="torque_nm differs at row 19"):
        build_design(m, s2)
    s3 = Samples(s.time_s + 0.5, s.torque_nm, s.angle_arcsec)
    with pytest.raises(DataFormatError, match="time_s differs"):
        build_design(m, s3)
    with pytest.raises(DataFormatError, match="same rows"):
        build_design(m, s.select(slice(0, 100)))


def test_sim_effects_table_round_trip_and_errors():
    table = {"time_skew": {"skew_s": 0.01}, "periodic_error": {"period_arcsec": 90.0, "amplitude_arcsec": 0.5,
                                                               "phase_rad": 0.1}}
    eff = effects_from_table(table)
    assert sorted(eff.active) == ["periodic_error", "time_skew"]
    assert effects_to_table(eff) == table
    assert from_config({}) is None
    assert from_config({"backlash": {"backlash_arcsec": 0.0}}) is None
    with pytest.raises(ConfigError, match="unknown effect"):
        effects_from_table({"wobble": {}})
    with pytest.raises(ConfigError, match="unknown key"):
        effects_from_table({"backlash": {"width": 1.0}})
    with pytest.raises(ConfigError, match="torque lag"):
        HiddenEffects({"time_skew": {"skew_s": -0.1}})
    with pytest.raises(ConfigError, match="missing parameter 'amplitude_arcsec'"):
        effects_from_table({"periodic_error": {"period_arcsec": 90.0}})
    # one vocabulary: the simulator takes exactly the catalogue's names and parameters
    from tcms_daq.discrepancy.catalogue import CATALOGUE

    every = {name: {k: 0.5 for k in effect.parameters} for name, effect in CATALOGUE.items()}
    assert sorted(effects_from_table(every).active) == sorted(CATALOGUE)


def test_sim_effects_batches_equal_one_piece():
    """The hook is stateful: a run cut into batches gives the same signals as in one piece."""
    table = {"time_skew": {"skew_s": 0.03}, "backlash": {"backlash_arcsec": 2.0},
             "torque_zero_offset": {"offset_nm": 5.0}, "thermal_drift": {"rate_arcsec_per_s": 0.1}}
    torque = triangle(noise=0.0)
    t = np.arange(len(torque)) * 0.01
    angle = 0.2 * torque + 3.0 * np.tanh(torque / 20.0)
    cols = {"time_s": t, "applied_torque_nm": torque, "true_angle_arcsec": angle, "torque_signal_nm": torque,
            "angle_signal_arcsec": angle}
    whole = from_config(table)(cols)
    hook = from_config(table)
    parts = [hook({k: v[a:a + 137] for k, v in cols.items()}) for a in range(0, len(t), 137)]
    for key in ("torque_signal_nm",):
        assert np.allclose(np.concatenate([p[key] for p in parts]), whole[key])
    # the slope of the zero-offset term is one-sided at batch edges: compare away from them
    joined = np.concatenate([p["angle_signal_arcsec"] for p in parts])
    inner = np.ones(len(t), dtype=bool)
    inner[::137] = False
    inner[136::137] = False
    assert np.allclose(joined[inner], whole["angle_signal_arcsec"][inner], atol=1e-6)


def test_separating_experiment_names_the_design_change():
    text = separating_experiment(["torsion_offset", "scale_error"])
    assert "lever arm" in text
    assert "rate" in separating_experiment(["time_skew", "backlash"])


def test_bench_config_switches_effects_on():
    """A [sim.effects] table in the bench config reaches the simulated bench through its effects hook."""
    from tcms_daq.sim.bench import SimulatedBench

    from tcms_daq.config import load_bench_config, load_reducers_for

    cfg = load_bench_config()
    reducer = load_reducers_for(cfg)[cfg.sim.reducer]
    runs = {}
    for label, table in (("off", {}), ("on", {"thermal_drift": {"rate_arcsec_per_s": 1.0}})):
        on = cfg.model_copy(update={"sim": cfg.sim.model_copy(update={"effects": table})})
        bench = SimulatedBench.from_config(on, reducer, seed=3)
        runs[label] = bench.advance(2.0)
    diff = runs["on"].angle_arcsec - runs["off"].angle_arcsec
    assert np.allclose(diff, runs["on"].time_s, atol=0.2)  # r·t with r = 1 ″/s (quantisation 0.1″)


def test_the_skew_shift_follows_the_lost_motion_zone_crossed_in_one_sample():
    """θ_sim(t + τ) between samples, where the lost-motion zone (12″ over ±10.8 N·m) is crossed in one 12 N·m
    step (600 N·m/s at 50 Hz): linear pieces cut its corner by 0.55–0.65″, spikes at every zero crossing that kept
    run 2 of the service's closed loop ``unexplained``; monotone cubic pieces 0.20–0.30″ (9 sampling phases)."""
    from tcms_daq.sim.physics import catalogue_model

    from tcms_daq.discrepancy.effects import skew_shift

    model = catalogue_model("RV-110E")
    corners, fine_t = [0.0, 1.0, 3.0, 4.0], np.arange(0.0, 4.2, 0.0005)
    fine = model.twist_arcsec(np.interp(fine_t, corners, [0.0, 600.0, -600.0, 0.0]))
    worst = []
    for phase in np.linspace(0.0, 0.02, 9, endpoint=False):
        t = np.arange(0.0, 4.0, 0.02) + phase
        torque = np.interp(t, corners, [0.0, 600.0, -600.0, 0.0])
        theta = np.interp(t, fine_t, fine)
        data = build_design(Samples(t, torque, theta + 1.0), Samples(t, torque, theta))
        exact = np.interp(t + 0.01, fine_t, fine) - theta
        crossing = (np.abs(torque) < 30.0) & (t > 0.1) & (t < 3.9)
        worst.append(float(np.max(np.abs(skew_shift(data, 0.01) - exact)[crossing])))
    assert max(worst) < 0.35, worst


def test_the_history_free_curve_of_branches_that_differ_has_no_saw_tooth():
    """The service's programme: 3 loops of ±800 N·m at 4 N·m a sample (200 N·m/s at 50 Hz), back to zero, then 3 at
    12 N·m a sample from zero. The RV-110E's friction loop remembers where a branch began (539 N·m), so the branches
    after the reversal at zero lie up to 1.2″ off the others; bin means over whichever branches have a sample in a
    bin made the curve a saw tooth of the fast branches' period, and the offset read off it came out 4.0 → 2.64 and
    8.0 → 7.65 N·m on the exact signature. Noise-free: the model's own midline is the truth."""
    from tcms_daq.sim.physics import catalogue_model, midline_twist_arcsec, twist_arcsec

    from tcms_daq.discrepancy import effects as fx

    parts, level = [np.zeros(1)], 0.0
    for step in (4.0, 12.0):
        for target in (-800.0, 800.0, -800.0, 800.0, -800.0, 800.0, -800.0, 0.0):
            n = int(np.ceil(abs(target - level) / step))
            parts.append(np.linspace(level, target, n + 1)[1:])
            level = target
    torque = np.concatenate(parts)
    params = catalogue_model("RV-110E").params
    angle = twist_arcsec(torque, params)[0]
    t = np.arange(len(torque)) * 0.02
    data = build_design(Samples(t, torque, angle), Samples(t, torque, angle))
    for offset_nm in (4.0, 8.0):
        exact = midline_twist_arcsec(torque - offset_nm, params) - midline_twist_arcsec(torque, params)
        error = fx.torque_shift(data, offset_nm) - exact
        assert np.std(error) < 0.15 * np.std(exact)  # 0.13 / 0.13 (0.81 / 0.59 with the saw tooth)
        grid = np.arange(offset_nm - 0.5, offset_nm + 0.51, 0.02)
        fitted = grid[int(np.argmin([np.std(exact - fx.torque_shift(data, g)) for g in grid]))]
        assert fitted == pytest.approx(offset_nm, abs=0.05)

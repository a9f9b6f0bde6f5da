"""Forward model of the reducer: catalogue curves, the closed smooth Dahl loop, the truth the tests compare to."""

from __future__ import annotations

import numpy as np
import pytest
from tcms_daq.sim.physics import (
    ReducerPhysics,
    TwistState,
    elastic_twist_arcsec,
    hysteresis_arcsec,
    loop_branches,
    loop_truth,
    physics_from_spec,
    steady_loop_state,
    twist_arcsec,
)

from tcms_daq.units import ARCSEC_PER_RAD


def _cycle(amplitude: float, n_loops: int, per_branch: int = 4001) -> np.ndarray:
    """0 → −A, then n loops −A → +A → −A (dense, exact turning points)."""
    up = np.linspace(-amplitude, amplitude, per_branch)
    parts = [np.linspace(0.0, -amplitude, per_branch // 2)]
    for _ in range(n_loops):
        parts += [up[1:], up[::-1][1:]]
    return np.concatenate(parts)


def test_hd_worked_example_through_the_forward_model(catalogue):
    # HFUC-32-100, 60 N·m → 7.15e-4 rad (2.5 arcmin): the elastic part of the sim physics
    params = physics_from_spec(catalogue["HFUC-32-100"])
    phi = elastic_twist_arcsec(60.0, params) / ARCSEC_PER_RAD
    assert phi == pytest.approx(7.15e-4, abs=0.005e-4)
    assert phi * 10800 / np.pi == pytest.approx(2.5, abs=0.05)
    # the full model without zone and hysteresis is exactly that curve, odd in the torque
    bare = ReducerPhysics(compliance_arcsec_per_nm=None, hd_breakpoints_nm=(29.0, 108.0),
                          hd_stiffness_nm_per_rad=(6.7e4, 1.1e5, 1.2e5))
    angle, _ = twist_arcsec(np.array([60.0, -60.0, 200.0]), bare)
    assert angle[0] / ARCSEC_PER_RAD == pytest.approx(29 / 6.7e4 + 31 / 1.1e5, rel=1e-12)
    assert angle[1] == -angle[0]
    assert angle[2] / ARCSEC_PER_RAD == pytest.approx(29 / 6.7e4 + 79 / 1.1e5 + 92 / 1.2e5, rel=1e-12)


@pytest.mark.parametrize("name", ["RV-110E", "RV-100C", "RV-60N"])
def test_rv_truth_equals_catalogue_at_rated_torque(catalogue, name):
    spec = catalogue[name]
    params = physics_from_spec(spec)
    truth = loop_truth(params, spec.rated_torque_nm, spec.rated_torque_nm, spec.lost_motion_pct)
    assert truth.rigidity_nm_per_arcmin == pytest.approx(spec.rigidity_nm_per_arcmin, rel=1e-12)
    assert truth.rigidity_pos_nm_per_arcmin == pytest.approx(truth.rigidity_neg_nm_per_arcmin, rel=1e-12)
    assert truth.backlash_arcsec == pytest.approx(spec.sim.backlash_arcsec, rel=1e-12)
    assert 0 < truth.lost_motion_arcsec < spec.lost_motion_limit_arcsec


def test_truth_matches_a_simulated_steady_loop(catalogue):
    """loop_truth (closed-form steady state) agrees with brute-force simulation after a conditioning loop."""
    spec = catalogue["RV-110E"]
    params = physics_from_spec(spec)
    a = 1078.0
    trace = _cycle(a, 6)
    angle, _ = twist_arcsec(trace, params)
    n = 4000
    last_up = slice(len(trace) - 2 * n - 1, len(trace) - n)
    last_down = slice(len(trace) - n - 1, len(trace))
    levels = np.array([0.0, 32.34, -32.34, 539.0, -539.0])
    up_exact, down_exact = loop_branches(params, a, levels)
    up_sim = np.interp(levels, trace[last_up], angle[last_up])
    down_sim = np.interp(levels, trace[last_down][::-1], angle[last_down][::-1])
    np.testing.assert_allclose(up_sim, up_exact, atol=1e-3)
    np.testing.assert_allclose(down_sim, down_exact, atol=1e-3)
    truth = loop_truth(params, a, a)
    assert abs(down_sim[0] - up_sim[0]) == pytest.approx(truth.backlash_arcsec, abs=1e-3)


def test_loop_is_closed_smooth_and_dissipative(catalogue):
    params = physics_from_spec(catalogue["RV-110E"])
    a = 1078.0
    trace = _cycle(a, 3)
    angle, state = twist_arcsec(trace, params)
    n = 4000
    # closed: the loop converges geometrically (factor e^{−4A/T_z} per loop) to one closed steady loop: after
    # one conditioning loop each loop returns to its start at −A within 1e-3″, after two within 1e-6″
    tips_minus = angle[n // 2 - 1 :: 2 * n]
    assert abs(tips_minus[2] - tips_minus[1]) < 1e-3
    assert abs(tips_minus[3] - tips_minus[2]) < 1e-6
    start = steady_loop_state(params, a)
    assert state.hysteresis_arcsec == pytest.approx(start.hysteresis_arcsec, abs=1e-8)
    # smooth: no jumps between neighbouring samples (ΔT = 0.54 N·m here; the steepest slope is < 1.5″/N·m)
    assert np.max(np.abs(np.diff(angle))) < 1.5 * (2 * a / (n - 1)) + 1e-9
    # rising branch below the falling one at zero torque; energy dissipated per cycle ∮T dθ > 0
    up, down = loop_branches(params, a, np.array([0.0]))
    assert up[0] < down[0]
    last = slice(len(trace) - 2 * n + 1, len(trace))
    energy = np.sum(0.5 * (trace[last][1:] + trace[last][:-1]) * np.diff(angle[last]))
    assert energy > 0


def test_loop_is_symmetric_so_the_midline_is_odd(catalogue):
    params = physics_from_spec(catalogue["RV-60N"])
    a = 568.0
    levels = np.linspace(-a, a, 41)
    up, down = loop_branches(params, a, levels)
    np.testing.assert_allclose(down, -up[::-1], atol=1e-9)  # z_↓(T) = −z_↑(−T)
    mid = 0.5 * (up + down)
    np.testing.assert_allclose(mid, -mid[::-1], atol=1e-9)
    assert mid[20] == pytest.approx(0.0, abs=1e-9)


def test_state_carries_across_batches(catalogue):
    params = physics_from_spec(catalogue["RV-100C"])
    rng = np.random.default_rng(1)
    trace = np.cumsum(rng.normal(0, 5.0, 5000))  # an arbitrary, noisy torque trace
    whole, s_whole = twist_arcsec(trace, params)
    pieces, state = [], None
    for chunk in np.array_split(trace, 7):
        out, state = twist_arcsec(chunk, params, state)
        pieces.append(out)
    np.testing.assert_allclose(np.concatenate(pieces), whole, rtol=0, atol=1e-9)
    assert state.hysteresis_arcsec == pytest.approx(s_whole.hysteresis_arcsec, abs=1e-9)


def test_hysteresis_is_rate_independent_and_exact_per_monotonic_stretch():
    params = ReducerPhysics(hysteresis_half_width_arcsec=10.0, hysteresis_torque_nm=50.0)
    coarse = np.array([0.0, 100.0, 300.0])
    fine = np.linspace(0.0, 300.0, 3001)
    z_coarse, _ = hysteresis_arcsec(coarse, params)
    z_fine, _ = hysteresis_arcsec(fine, params)
    closed = -10.0 * (1 - np.exp(-coarse / 50.0))  # z = −h + (z0 + h)·exp(−ΔT/T_z), z0 = 0
    np.testing.assert_allclose(z_coarse, closed, atol=1e-12)
    assert z_fine[-1] == pytest.approx(closed[-1], abs=1e-12)


def test_long_traces_do_not_overflow():
    params = ReducerPhysics(hysteresis_half_width_arcsec=10.0, hysteresis_torque_nm=1.0)
    trace = np.tile(np.concatenate([np.linspace(-500, 500, 1001), np.linspace(500, -500, 1001)]), 20)
    z, _ = hysteresis_arcsec(trace, params)
    assert np.all(np.isfinite(z)) and np.max(np.abs(z)) <= 10.0 + 1e-9
    z_jump, state = hysteresis_arcsec(np.array([0.0, 1e6]), params, TwistState(0.0, 3.0))
    assert z_jump[-1] == pytest.approx(-10.0) and state.torque_nm == 1e6


def test_parameters_are_validated():
    with pytest.raises(ValueError, match="compliance_arcsec_per_nm must be > 0"):
        ReducerPhysics(compliance_arcsec_per_nm=-1.0)
    with pytest.raises(ValueError, match="Harmonic Drive curve"):
        ReducerPhysics(compliance_arcsec_per_nm=None)

"""Hysteresis evaluation against synthetic loops with analytically known truth (see conftest.py)."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from tcms_daq.analysis import Limits, evaluate, format_evaluation
from tcms_daq.analysis.interpolation import angle_at_torque
from tcms_daq.errors import EvaluationError
from tcms_daq.units import ARCSEC_PER_RAD

RATED = 1078.0


def run(record, **kwargs):
    kwargs.setdefault("rated_torque_nm", record.model.rated_torque_nm)
    return evaluate(record.time_s, record.torque_nm, record.angle_arcsec, **kwargs)


def test_noiseless_rv110e_recovers_truth(synth, loop_model):
    model = loop_model()
    ev = run(synth(model))
    # The model's midline is linear above the lost-motion zone, so any secant interval gives K exactly.
    assert ev.rigidity_nm_per_arcmin == pytest.approx(294.0, rel=1e-3)
    assert ev.backlash_arcsec == pytest.approx(25.0, abs=0.05)
    assert ev.lost_motion_arcsec == pytest.approx(model.lost_motion_arcsec(3.0), abs=0.05)
    for side in ("positive", "negative"):
        assert ev.per_direction[side].rigidity_nm_per_arcmin == pytest.approx(294.0, rel=1e-3)
    assert ev.n_loops == 4 and len(ev.loops) == 4  # conditioning loop + 3, none skipped by default
    assert ev.test_torque_nm == RATED
    assert ev.lost_motion_torque_nm == pytest.approx(0.03 * RATED)
    assert ev.loading_rate_nm_per_s == pytest.approx(100.0, rel=1e-3)
    assert ev.fit_window_samples == 2  # noiseless data: exact interpolation
    # Loop area: ∫ B·(1 − (T/A)²) dT over ±A = B·4A/3 (arcsec·N·m) → J.
    assert ev.loop_energy_j == pytest.approx(25.0 * 4.0 * RATED / 3.0 / ARCSEC_PER_RAD, rel=1e-3)


@pytest.mark.parametrize("seed", [0, 1, 2, 3, 4])
def test_noisy_rv110e_within_tolerance(synth, loop_model, seed):
    model = loop_model()
    ev = run(synth(model, torque_noise_nm=0.5, angle_noise_arcsec=0.2, seed=seed), skip_loops=1)
    assert ev.rigidity_nm_per_arcmin == pytest.approx(294.0, rel=0.01)
    assert ev.backlash_arcsec == pytest.approx(25.0, abs=0.5)
    assert ev.lost_motion_arcsec == pytest.approx(model.lost_motion_arcsec(3.0), abs=0.5)
    assert ev.n_loops == 3 and ev.skipped_loops == 1
    assert [lp.evaluated for lp in ev.loops] == [False, True, True, True]
    assert ev.std["rigidity_nm_per_arcmin"] is not None and ev.std["rigidity_nm_per_arcmin"] < 1.0
    assert ev.loop_energy_j == pytest.approx(25.0 * 4.0 * RATED / 3.0 / ARCSEC_PER_RAD, rel=0.01)
    assert ev.noise["torque_nm"] == pytest.approx(0.5, rel=0.1)
    assert ev.noise["angle_arcsec"] == pytest.approx(0.2, rel=0.1)


@pytest.mark.parametrize("seed", [10, 11, 12])
def test_noisy_low_sample_rate(synth, loop_model, seed):
    """50 Hz at 100 Nm/s: 2 Nm between samples, windows stay within 1 % of the test torque."""
    model = loop_model()
    rec = synth(model, sample_rate_hz=50.0, torque_noise_nm=0.5, angle_noise_arcsec=0.2, seed=seed)
    ev = run(rec)
    assert ev.rigidity_nm_per_arcmin == pytest.approx(294.0, rel=0.01)
    assert ev.backlash_arcsec == pytest.approx(25.0, abs=0.5)
    assert ev.lost_motion_arcsec == pytest.approx(model.lost_motion_arcsec(3.0), abs=0.5)


def test_mirrored_profile_gives_down_up_loops(synth, loop_model):
    model = loop_model()
    ev = run(synth(model, first_sign=+1))
    assert {lp.order for lp in ev.loops} == {"down-up"}
    assert ev.rigidity_nm_per_arcmin == pytest.approx(294.0, rel=1e-3)
    assert ev.backlash_arcsec == pytest.approx(25.0, abs=0.05)
    assert ev.lost_motion_arcsec == pytest.approx(model.lost_motion_arcsec(3.0), abs=0.05)


def test_interval_is_a_parameter(synth, loop_model):
    """A stiffening midline (cubic term): the secant depends on the interval and matches the closed form."""
    model = loop_model(cubic_arcsec_per_nm3=-3e-8)
    rec = synth(model)
    ev_default = run(rec)
    ev_narrow = run(rec, rigidity_interval=(0.2, 0.7))
    lo, hi = ev_default.per_direction["positive"].interval_nm
    assert lo == pytest.approx(0.5 * RATED) and hi == pytest.approx(RATED)
    assert ev_default.rigidity_nm_per_arcmin == pytest.approx(model.secant_rigidity_nm_per_arcmin(lo, hi), rel=1e-3)
    truth_narrow = model.secant_rigidity_nm_per_arcmin(0.2 * RATED, 0.7 * RATED)
    assert ev_narrow.rigidity_nm_per_arcmin == pytest.approx(truth_narrow, rel=1e-3)
    assert abs(ev_narrow.rigidity_nm_per_arcmin - ev_default.rigidity_nm_per_arcmin) > 5.0
    assert ev_narrow.rigidity_interval == (0.2, 0.7)


def test_test_torque_below_rated_is_taken_from_the_data(synth, loop_model):
    model = loop_model(test_torque_nm=600.0, cubic_arcsec_per_nm3=-3e-8)
    ev = run(synth(model))
    assert ev.test_torque_nm == pytest.approx(600.0, abs=0.1)
    assert ev.per_direction["negative"].interval_nm[0] == pytest.approx(300.0, abs=0.1)
    truth = model.secant_rigidity_nm_per_arcmin(300.0, 600.0)
    assert ev.rigidity_nm_per_arcmin == pytest.approx(truth, rel=1e-3)
    # Lost motion stays at 3 % of the rated torque, not of the test torque.
    assert ev.lost_motion_arcsec == pytest.approx(model.lost_motion_arcsec(3.0), abs=0.05)


def test_explicit_test_torque_and_lost_motion_level(synth, loop_model):
    model = loop_model(cubic_arcsec_per_nm3=-3e-8)
    ev = run(synth(model), test_torque_nm=1000.0, lost_motion_pct=5.0)
    assert ev.test_torque_nm == 1000.0
    assert ev.lost_motion_torque_nm == pytest.approx(0.05 * RATED)
    assert ev.lost_motion_arcsec == pytest.approx(model.lost_motion_arcsec(5.0), abs=0.05)
    assert ev.rigidity_nm_per_arcmin == pytest.approx(model.secant_rigidity_nm_per_arcmin(500.0, 1000.0), rel=1e-3)


def test_stepped_profile_with_dwell(synth_stepped, loop_model):
    model = loop_model()
    ev = run(synth_stepped(model))
    assert ev.rigidity_nm_per_arcmin == pytest.approx(294.0, rel=1e-3)
    assert ev.backlash_arcsec == pytest.approx(25.0, abs=0.05)
    assert ev.lost_motion_arcsec == pytest.approx(model.lost_motion_arcsec(3.0), abs=0.05)
    noisy = run(synth_stepped(model, torque_noise_nm=0.5, angle_noise_arcsec=0.2, seed=3))
    assert noisy.rigidity_nm_per_arcmin == pytest.approx(294.0, rel=0.01)
    assert noisy.backlash_arcsec == pytest.approx(25.0, abs=0.5)
    assert noisy.lost_motion_arcsec == pytest.approx(model.lost_motion_arcsec(3.0), abs=0.5)


def test_quantised_encoder(synth, loop_model):
    """ND 287 display resolution 0.0001° = 0.36″: rounding is treated as noise."""
    model = loop_model()
    rec = synth(model, torque_noise_nm=0.5, seed=5)
    rec.angle_arcsec = np.round(rec.angle_arcsec / 0.36) * 0.36
    ev = run(rec)
    assert ev.noise["angle_arcsec"] > 0.05
    assert ev.backlash_arcsec == pytest.approx(25.0, abs=0.5)
    assert ev.lost_motion_arcsec == pytest.approx(model.lost_motion_arcsec(3.0), abs=0.5)
    assert ev.rigidity_nm_per_arcmin == pytest.approx(294.0, rel=0.01)


def test_single_loop_has_no_std(synth, loop_model):
    ev = run(synth(loop_model(), loops=1, conditioning_loops=0))
    assert ev.n_loops == 1
    assert ev.std["rigidity_nm_per_arcmin"] is None
    assert ev.to_dict()["std"]["backlash_arcsec"] is None


def test_limits_verdict(rv110e_record):
    passing = run(rv110e_record, limits=Limits(rigidity_min_nm_per_arcmin=280.0, backlash_max_arcsec=60.0,
                                                 lost_motion_max_arcsec=60.0))
    assert passing.verdict["passed"] is True
    assert set(passing.verdict["checks"]) == {"rigidity_min_nm_per_arcmin", "backlash_max_arcsec",
                                              "lost_motion_max_arcsec"}
    failing = run(rv110e_record, limits=Limits(rigidity_min_nm_per_arcmin=300.0, backlash_max_arcsec=20.0))
    assert failing.verdict["passed"] is False
    assert failing.verdict["checks"]["rigidity_min_nm_per_arcmin"]["passed"] is False
    assert failing.verdict["checks"]["backlash_max_arcsec"]["passed"] is False
    assert failing.verdict["checks"]["backlash_max_arcsec"]["value"] == pytest.approx(25.0, abs=0.05)
    assert "FAIL" in format_evaluation(failing)
    assert run(rv110e_record).verdict is None


def test_to_dict_is_json_with_the_contract_keys(rv110e_record):
    d = json.loads(json.dumps(run(rv110e_record, hd_breakpoints_nm=(300.0, 700.0)).to_dict(), allow_nan=False))
    for key in ("rigidity_nm_per_arcmin", "lost_motion_arcsec", "backlash_arcsec", "loops", "n_loops",
                "per_direction", "std", "loading_rate_nm_per_s", "test_torque_nm", "lost_motion_torque_nm",
                "rigidity_interval", "k1_nm_per_rad", "k2_nm_per_rad", "k3_nm_per_rad", "verdict"):
        assert key in d, key
    assert set(d["per_direction"]) == {"positive", "negative"}
    assert d["per_direction"]["negative"]["rigidity_nm_per_arcmin"] == pytest.approx(294.0, rel=1e-3)
    assert len(d["loops"]) == d["n_loops"] == 4
    assert d["loops"][0]["per_direction"]["positive"]["interval_nm"][0] == pytest.approx(539.0)


def test_angle_offset_and_time_offset_do_not_matter(synth, loop_model):
    a = run(synth(loop_model(), angle_offset_arcsec=0.0, time_offset_s=0.0))
    b = run(synth(loop_model(), angle_offset_arcsec=-5000.0, time_offset_s=1e6))
    assert b.rigidity_nm_per_arcmin == pytest.approx(a.rigidity_nm_per_arcmin, rel=1e-9)
    assert b.backlash_arcsec == pytest.approx(a.backlash_arcsec, abs=1e-6)
    assert b.lost_motion_arcsec == pytest.approx(a.lost_motion_arcsec, abs=1e-6)


def test_two_sample_window_is_exact_linear_interpolation():
    rng = np.random.default_rng(1)
    torque = np.cumsum(rng.uniform(0.1, 3.0, 200)) - 200.0
    angle = np.sin(torque / 40.0) * 30.0
    levels = rng.uniform(torque[0], torque[-1], 50)
    time = np.arange(torque.size) * 0.01
    got = angle_at_torque(time, torque, angle, torque, +1, levels, window=2)
    np.testing.assert_allclose(got, np.interp(levels, torque, angle), atol=1e-9)
    # B↓ branch: same data traversed downwards.
    got_down = angle_at_torque(time, torque[::-1], angle[::-1], torque[::-1], -1, levels, window=2)
    np.testing.assert_allclose(got_down, np.interp(levels, torque, angle), atol=1e-9)
    outside = angle_at_torque(time, torque, angle, torque, +1, np.array([torque[0] - 1, torque[-1] + 1]), window=2)
    assert np.isnan(outside).all()


def test_aborted_last_branch_is_not_a_loop(synth, loop_model):
    """A test cut off at +600 Nm on the way up: the complete loops are evaluated, the partial one is not."""
    model = loop_model()
    rec = synth(model, loops=3, conditioning_loops=0)
    # Loops end at −T; cut the record when the torque next rises through +600 Nm after the last full loop.
    last_full = rec.time_s[0] + (1078.0 + 2 * 4 * 1078.0) / 100.0  # lead-in + two loops at 100 Nm/s
    keep = rec.time_s <= last_full + (1078.0 + 600.0) / 100.0
    cut = dataclasses.replace(rec, time_s=rec.time_s[keep], torque_nm=rec.torque_nm[keep],
                              angle_arcsec=rec.angle_arcsec[keep], true_torque_nm=rec.true_torque_nm[keep])
    assert cut.torque_nm[-1] == pytest.approx(600.0, abs=1.0)
    ev = run(cut)
    assert ev.n_loops == 2
    assert ev.backlash_arcsec == pytest.approx(25.0, abs=0.05)


def test_torque_zero_offset_only_shifts_the_levels(synth, loop_model):
    """A 2 Nm sensor zero offset moves every level by 2 Nm; rigidity is unaffected, backlash barely."""
    model = loop_model()
    rec = synth(model)
    ev = evaluate(rec.time_s, rec.torque_nm + 2.0, rec.angle_arcsec, rated_torque_nm=RATED)
    assert ev.rigidity_nm_per_arcmin == pytest.approx(294.0, rel=2e-3)
    assert ev.backlash_arcsec == pytest.approx(float(np.diff(model.angle_arcsec(-2.0, np.array([1, -1])))[0]),
                                               abs=0.05)


def test_a_smaller_run_in_loop_is_not_a_full_loop(synth, loop_model):
    """A ±400 Nm run-in loop before the ±1078 Nm test is not mistaken for a loop of the test."""
    model = loop_model()
    small = synth(loop_model(test_torque_nm=400.0), loops=1, conditioning_loops=0)
    big = synth(model, loops=2, conditioning_loops=0)
    time_s = np.concatenate((small.time_s, big.time_s + small.time_s[-1] + 0.01 - big.time_s[0]))
    torque = np.concatenate((small.torque_nm, big.torque_nm))
    angle = np.concatenate((small.angle_arcsec, big.angle_arcsec))
    # The small loop's turning points are below 90 % of the typical one: not full, so not a loop at all.
    ev = evaluate(time_s, torque, angle, rated_torque_nm=RATED)
    assert ev.n_loops == 2
    assert ev.backlash_arcsec == pytest.approx(25.0, abs=0.05)


def test_a_skipped_loop_that_cannot_be_evaluated_is_only_a_warning(synth, loop_model):
    rec = synth(loop_model(), loops=2, conditioning_loops=1)
    end_of_conditioning = rec.time_s[0] + (1078.0 + 4 * 1078.0) / 100.0
    angle = rec.angle_arcsec.copy()
    angle[rec.time_s < end_of_conditioning - 1.0] = 0.0  # encoder not yet reading during the run-in loop
    ev = evaluate(rec.time_s, rec.torque_nm, angle, rated_torque_nm=RATED, skip_loops=1)
    assert ev.n_loops == 2 and [lp.index for lp in ev.loops] == [1, 2]
    assert any("skipped loop 0 not reported" in w for w in ev.warnings)
    assert ev.rigidity_nm_per_arcmin == pytest.approx(294.0, rel=1e-3)
    with pytest.raises(EvaluationError, match="angle does not increase"):
        evaluate(rec.time_s, rec.torque_nm, angle, rated_torque_nm=RATED)

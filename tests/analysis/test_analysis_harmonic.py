"""Harmonic Drive K1/K2/K3: the catalogue formula (worked example) and recovery from a synthetic curve."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tcms_daq.analysis import evaluate, hd_torsion_angle_rad
from tcms_daq.analysis.harmonic import hd_regions
from tcms_daq.units import ARCMIN_PER_RAD

HFUC_32_100 = dict(t1_nm=29.0, t2_nm=108.0, k1_nm_per_rad=6.7e4, k2_nm_per_rad=1.1e5, k3_nm_per_rad=1.2e5)


def test_worked_example_hfuc_32_100():
    phi = hd_torsion_angle_rad(60.0, **HFUC_32_100)
    assert phi == pytest.approx(29 / 6.7e4 + 31 / 1.1e5, rel=1e-12)
    assert phi == pytest.approx(7.15e-4, abs=0.005e-4)  # the manual's 7.15e-4 rad
    assert round(phi * ARCMIN_PER_RAD, 1) == 2.5  # = 2.5 arcmin


def test_formula_regions_and_symmetry():
    t = np.array([-150.0, -29.0, 0.0, 10.0, 29.0, 108.0, 150.0])
    phi = hd_torsion_angle_rad(t, **HFUC_32_100)
    assert phi[2] == 0.0
    assert phi[3] == pytest.approx(10 / 6.7e4)
    assert phi[4] == pytest.approx(29 / 6.7e4)
    assert phi[5] == pytest.approx(29 / 6.7e4 + 79 / 1.1e5)
    assert phi[6] == pytest.approx(29 / 6.7e4 + 79 / 1.1e5 + 42 / 1.2e5)
    assert phi[0] == -phi[6] and phi[1] == -phi[4]


def test_regions_clip_to_the_reached_torque():
    assert hd_regions((29.0, 108.0), 150.0) == [(0.0, 29.0), (29.0, 108.0), (108.0, 150.0)]
    assert hd_regions((29.0, 108.0), 80.0) == [(0.0, 29.0), (29.0, 80.0), None]
    with pytest.raises(ValueError):
        hd_regions((108.0, 29.0), 150.0)


def _evaluate(rec):
    return evaluate(rec.time_s, rec.torque_nm, rec.angle_arcsec, rated_torque_nm=rec.model.rated_torque_nm,
                    lost_motion_pct=4.0, hd_breakpoints_nm=(rec.model.t1_nm, rec.model.t2_nm))


def test_recovers_k1_k2_k3_from_a_synthetic_curve(synth, hd_model):
    model = hd_model()
    ev = _evaluate(synth(model, rate_nm_per_s=10.0, sample_rate_hz=200.0))
    assert ev.k1_nm_per_rad == pytest.approx(6.7e4, rel=0.005)
    assert ev.k2_nm_per_rad == pytest.approx(1.1e5, rel=0.005)
    assert ev.k3_nm_per_rad == pytest.approx(1.2e5, rel=0.005)
    for side in ("positive", "negative"):
        assert ev.per_direction[side].k1_nm_per_rad == pytest.approx(6.7e4, rel=0.005)
    # The recovered constants reproduce the worked example.
    phi = hd_torsion_angle_rad(60.0, 29.0, 108.0, ev.k1_nm_per_rad, ev.k2_nm_per_rad, ev.k3_nm_per_rad)
    assert phi == pytest.approx(7.15e-4, rel=0.005)
    assert ev.backlash_arcsec == pytest.approx(model.backlash_arcsec, abs=0.05)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_recovers_k_with_noise(synth, hd_model, seed):
    model = hd_model()
    rec = synth(model, rate_nm_per_s=10.0, sample_rate_hz=200.0, torque_noise_nm=0.05, angle_noise_arcsec=0.2,
                seed=seed)
    ev = _evaluate(rec)
    for key, truth in (("k1_nm_per_rad", 6.7e4), ("k2_nm_per_rad", 1.1e5), ("k3_nm_per_rad", 1.2e5)):
        assert getattr(ev, key) == pytest.approx(truth, rel=0.01), key
    assert ev.std["k1_nm_per_rad"] is not None and math.isfinite(ev.std["k1_nm_per_rad"])


def test_no_k3_when_torque_stays_below_t2(synth, hd_model):
    model = hd_model(test_torque_nm=90.0)
    ev = _evaluate(synth(model, rate_nm_per_s=10.0, sample_rate_hz=200.0))
    assert ev.k1_nm_per_rad == pytest.approx(6.7e4, rel=0.005)
    assert ev.k2_nm_per_rad == pytest.approx(1.1e5, rel=0.005)
    assert ev.k3_nm_per_rad is None


def test_no_hd_keys_without_breakpoints(rv110e_record):
    d = evaluate(rv110e_record.time_s, rv110e_record.torque_nm, rv110e_record.angle_arcsec,
                 rated_torque_nm=1078.0).to_dict()
    assert d["k1_nm_per_rad"] is None and d["hd_breakpoints_nm"] is None

"""Inputs that must not pass silently (issue 11 item 6): a degrees file, a loop at 85 % amplitude, 0.05″/s drift,
coarse sampling, a rigidity far from the catalogue; numbers print as numbers. Records from tests/uncertainty/physics.py."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tcms_daq.analysis import evaluate
from tcms_daq.cli import main
from tcms_daq.config import get_reducer, load_reducer_catalogue
from tcms_daq.procedure.evaluation import evaluate_for_reducer
from tcms_daq.samples import Samples
from tcms_daq.uncertainty.budget import SAMPLING_LINE

from .physics import Chain, Reducer, measure, triangle, twist_arcsec

NO_ERRORS = Chain(0.0, 0.0, 0.0, 0.0, 0.0)


def clean_run(**kw):
    return measure(Reducer(), NO_ERRORS, np.random.default_rng(0), rate_nm_per_s=250.0, sample_rate_hz=200.0, **kw)


def test_a_clean_run_has_no_warning():
    ev = evaluate(*clean_run(), rated_torque_nm=1000.0)
    assert ev.warnings == []


def test_degrees_file_warns_with_both_readings():
    t, torque, angle = clean_run()
    ev = evaluate(t, torque, angle / 3600.0, rated_torque_nm=1000.0)
    (w,) = [w for w in ev.warnings if "degrees" in w]
    assert "is angle_arcsec in degrees or radians" in w
    span = np.ptp(angle / 3600.0)
    assert f"{span * 3600:.4g}″" in w  # what the span would be in degrees, as a number


def test_degrees_file_against_the_catalogue_names_the_unit(tmp_path):
    spec = get_reducer(load_reducer_catalogue(), "RV-110E")
    time_s, torque = triangle(1078.0, 3, 500.0, 200.0)
    angle = twist_arcsec(torque, Reducer(rigidity_nm_per_arcmin=294.0)) / 3600.0
    ev = evaluate_for_reducer(Samples(time_s, torque, angle), spec)
    (w,) = [w for w in ev.warnings if "catalogue" in w]
    assert "as if the angle were in degrees (× 3600)" in w and "RV-110E" in w


def test_a_loop_at_85_percent_amplitude_is_named_with_its_amplitude():
    time_s, torque = triangle(1000.0, 4, 250.0, 200.0)
    # the third turning point (the second −T) only reaches 85 %
    tips = np.flatnonzero(np.abs(np.diff(np.sign(np.diff(torque)))) > 0)
    t_low = time_s[tips[4]]
    torque = np.where(np.abs(time_s - t_low) < 0.8 + 150.0 / 250.0,
                      np.clip(torque, -850.0, None), torque)
    angle = twist_arcsec(torque, Reducer())
    ev = evaluate(time_s, torque, angle, rated_torque_nm=1000.0)
    (w,) = [w for w in ev.warnings if "reduced amplitude" in w]
    assert "-850 N·m" in w and "85%" in w and "not evaluated" in w
    assert "np.float64" not in w


def test_drift_of_0_05_arcsec_per_second_warns_and_is_corrected():
    t, torque, angle = clean_run()
    plain = evaluate(t, torque, angle, rated_torque_nm=1000.0)
    drifted = evaluate(*clean_run(drift_arcsec_per_s=0.05), rated_torque_nm=1000.0)
    (w,) = [w for w in drifted.warnings if "does not close" in w]
    assert "drifts by +0.0497″/s" in w and "drift-corrected backlash" in w and "results are drift-corrected" in w
    assert drifted.closure["drift_rate_arcsec_per_s"] == pytest.approx(0.05, rel=0.05)
    assert drifted.closure["corrected"] is True
    # the drift widens the loop; the reported results are the drift-corrected ones, the undrifted loop's
    assert drifted.closure["uncorrected_backlash_arcsec"] - plain.backlash_arcsec > 0.2
    assert drifted.backlash_arcsec == pytest.approx(plain.backlash_arcsec, abs=0.02)
    assert drifted.closure["drift_corrected_backlash_arcsec"] == drifted.backlash_arcsec
    assert drifted.lost_motion_arcsec == pytest.approx(plain.lost_motion_arcsec, abs=0.02)
    assert abs(plain.closure["drift_rate_arcsec_per_s"]) < 0.002 and plain.closure["corrected"] is False


def test_sampling_too_coarse_for_the_lost_motion_warns():
    time_s, torque = triangle(1000.0, 3, 250.0, 5.0)  # 50 N·m between samples; lost motion read at ±30 N·m
    angle = twist_arcsec(torque, Reducer())
    ev = evaluate(time_s, torque, angle, rated_torque_nm=1000.0)
    (w,) = [w for w in ev.warnings if "sampling too coarse" in w]
    assert "±30 N·m" in w


def test_messages_print_numbers_not_numpy_reprs(capsys, tmp_path):
    path = tmp_path / "back.csv"
    path.write_text("time_s,torque_nm,angle_arcsec\n" + "".join(
        f"{t},{q},{a}\n" for t, q, a in zip([0, 1, 0.5] + list(range(2, 30)), range(31), range(31), strict=True)))
    assert main(["analyze", str(path), "--rated-torque", "100"]) == 2
    err = capsys.readouterr().err
    assert "not strictly increasing" in err and "np.float64" not in err and "(1 s then 0.5 s)" in err


def test_analyze_json_carries_uncertainty_decision_and_warnings(tmp_path, capsys):
    t, torque, angle = measure(Reducer(rigidity_nm_per_arcmin=294.0), Chain(), np.random.default_rng(1),
                               amplitude_nm=1078.0, rate_nm_per_s=250.0, sample_rate_hz=200.0,
                               drift_arcsec_per_s=0.05)
    csv = tmp_path / "run.csv"
    csv.write_text("time_s,torque_nm,angle_arcsec\n" + "".join(f"{a},{b},{c}\n" for a, b, c in zip(t, torque, angle,
                                                                                                  strict=True)))
    unc = tmp_path / "chain.toml"
    unc.write_text("[torque]\nu_rel = 0.002\n[angle]\nu_rel = 0.002\nu_arcsec = 0.0\n")
    assert main(["analyze", str(csv), "--reducer", "RV-110E", "--uncertainty", str(unc), "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    rig = d["uncertainty"]["rigidity_nm_per_arcmin"]
    assert set(rig) >= {"value", "u", "U", "k", "dof", "unit", "dominant", "budget"}
    assert rig["U"] == pytest.approx(rig["k"] * rig["u"])
    assert {line["source"] for line in rig["budget"]} >= {"torque scale", "angle scale"}
    assert d["uncertainty_basis"] == f"declared chain: {unc}"
    assert d["verdict"]["rule"] == "guarded" and d["verdict"]["decision"] in ("pass", "undecided", "fail")
    assert any("does not close" in w for w in d["warnings"])
    # without the file: Type A only, and said so
    assert main(["analyze", str(csv), "--reducer", "RV-110E", "--json", "--decision-rule", "simple"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["uncertainty_basis"] == "type A only (no --uncertainty file)"
    assert d["verdict"]["rule"] == "simple"
    assert all(line["type"] == "A" or line["source"] == SAMPLING_LINE for e in d["uncertainty"].values()
               for line in e["budget"])


@pytest.mark.parametrize("content, message", [
    ("[torque]\nu_rel = -0.1\n", "torque.u_rel"),
    ("[torque]\nbogus = 1\n", "torque.bogus: unknown key"),
    ("[angle\n", "invalid TOML"),
])
def test_bad_uncertainty_file_is_one_line(tmp_path, capsys, content, message):
    csv = tmp_path / "run.csv"
    t, torque, angle = clean_run()
    csv.write_text("time_s,torque_nm,angle_arcsec\n" + "".join(f"{a},{b},{c}\n" for a, b, c in zip(t, torque, angle,
                                                                                                  strict=True)))
    bad = tmp_path / "u.toml"
    bad.write_text(content)
    assert main(["analyze", str(csv), "--rated-torque", "1000", "--uncertainty", str(bad)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and message in err and "Traceback" not in err

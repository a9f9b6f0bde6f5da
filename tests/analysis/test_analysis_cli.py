"""`tcms analyze`: output formats and every error path of a malformed file."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tcms_daq.analysis import evaluate
from tcms_daq.cli import main
from tcms_daq.samples import Samples, write_csv


@pytest.fixture
def csv_file(tmp_path, synth, loop_model):
    rec = synth(loop_model(), torque_noise_nm=0.5, angle_noise_arcsec=0.2, seed=7, sample_rate_hz=200.0)
    path = tmp_path / "test.csv"
    write_csv(path, Samples(rec.time_s, rec.torque_nm, rec.angle_arcsec))
    return path, rec


def analyze(capsys, *args):
    code = main(["analyze", *map(str, args)])
    out, err = capsys.readouterr()
    return code, out, err


def test_table_output(capsys, csv_file):
    path, _ = csv_file
    code, out, err = analyze(capsys, path, "--rated-torque", 1078)
    assert code == 0 and err == ""
    assert "rigidity [Nm/arcmin]" in out and "lost motion [arcsec]" in out and "backlash [arcsec]" in out
    assert "294." in out


def test_json_output_is_one_object_matching_evaluate(capsys, csv_file):
    path, rec = csv_file
    code, out, _ = analyze(capsys, path, "--rated-torque", 1078, "--json", "--skip-loops", 1)
    assert code == 0
    d = json.loads(out)  # exactly one JSON document on stdout
    for key in ("rigidity_nm_per_arcmin", "lost_motion_arcsec", "backlash_arcsec", "loops", "per_direction",
                "std", "loading_rate_nm_per_s", "test_torque_nm"):
        assert key in d
    assert d["per_direction"]["positive"]["rigidity_nm_per_arcmin"] == pytest.approx(294.0, rel=0.01)
    assert d["n_loops"] == 3 and d["skipped_loops"] == 1
    # The CSV round trip is exact, so the CLI reproduces the library numbers.
    ev = evaluate(rec.time_s, rec.torque_nm, rec.angle_arcsec, rated_torque_nm=1078.0, skip_loops=1)
    assert d["rigidity_nm_per_arcmin"] == ev.rigidity_nm_per_arcmin
    assert d["backlash_arcsec"] == ev.backlash_arcsec


def test_options_interval_percent_lost_motion_and_hd(capsys, csv_file):
    path, _ = csv_file
    code, out, _ = analyze(capsys, path, "--rated-torque", 1078, "--json", "--interval", 20, 80,
                           "--lost-motion-pct", 5, "--test-torque", 1000, "--hd-breakpoints", 300, 700)
    assert code == 0
    d = json.loads(out)
    assert d["rigidity_interval"] == [0.2, 0.8]
    assert d["lost_motion_torque_nm"] == pytest.approx(53.9)
    assert d["test_torque_nm"] == 1000.0
    assert d["k2_nm_per_rad"] is not None


def write_text(tmp_path, text: str):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    return path


def assert_one_line_error(capsys, path, *needles):
    code, out, err = analyze(capsys, path, "--rated-torque", 1078, "--json")
    assert code != 0
    assert out == ""
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    for needle in needles:
        assert needle in lines[0], lines[0]


def test_missing_column(capsys, tmp_path, csv_file):
    path, _ = csv_file
    text = path.read_text().replace("angle_arcsec", "angle_deg", 1)
    assert_one_line_error(capsys, write_text(tmp_path, text), "missing column 'angle_arcsec'")


def test_non_numeric_value(capsys, tmp_path, csv_file):
    path, _ = csv_file
    lines = path.read_text().splitlines()
    fields = lines[10].split(",")
    fields[1] = "12.5Nm"
    lines[10] = ",".join(fields)
    assert_one_line_error(capsys, write_text(tmp_path, "\n".join(lines) + "\n"),
                          "non-numeric value '12.5Nm'", "torque_nm", "line 11")


def test_too_few_samples(capsys, tmp_path):
    rows = "\n".join(f"{i * 0.01},{i * 10.0},{i * 2.0}" for i in range(5))
    assert_one_line_error(capsys, write_text(tmp_path, "time_s,torque_nm,angle_arcsec\n" + rows + "\n"),
                          "too few samples: 5")


def test_header_only(capsys, tmp_path):
    assert_one_line_error(capsys, write_text(tmp_path, "time_s,torque_nm,angle_arcsec\n"), "too few samples: 0")


def test_no_full_loop(capsys, tmp_path):
    t = np.linspace(0.0, 20.0, 400)
    torque = np.interp(t, [0, 10, 20], [0, 1078, 0])
    path = tmp_path / "ramp.csv"
    write_csv(path, Samples(t, torque, torque * 0.2))
    assert_one_line_error(capsys, path, "no full hysteresis loop")


def test_non_monotonic_time(capsys, tmp_path, csv_file):
    path, _ = csv_file
    lines = path.read_text().splitlines()
    lines[20], lines[21] = lines[21], lines[20]
    assert_one_line_error(capsys, write_text(tmp_path, "\n".join(lines) + "\n"), "time_s is not strictly increasing")


def test_missing_file(capsys, tmp_path):
    assert_one_line_error(capsys, tmp_path / "nope.csv", "no such file")


def test_bad_interval(capsys, csv_file):
    path, _ = csv_file
    code, _, err = analyze(capsys, path, "--rated-torque", 1078, "--interval", 0.9, 0.5)
    assert code == 2 and "--interval" in err


def test_reducer_from_catalogue_sets_limits_and_level(capsys, csv_file):
    path, _ = csv_file
    code, out, _ = analyze(capsys, path, "--reducer", "RV-110E", "--json")
    assert code == 0
    d = json.loads(out)
    assert d["reducer"] == "RV-110E" and d["rated_torque_nm"] == 1078.0
    assert d["verdict"]["passed"] is True
    assert "backlash_max_arcsec" in d["verdict"]["checks"]
    # An explicit option overrides the catalogue.
    code, out, _ = analyze(capsys, path, "--reducer", "RV-110E", "--lost-motion-pct", 5, "--json")
    assert json.loads(out)["lost_motion_pct"] == 5.0


def test_rated_torque_or_reducer_is_required(capsys, csv_file):
    path, _ = csv_file
    code = main(["analyze", str(path)])
    _, err = capsys.readouterr()
    assert code == 2 and "--rated-torque" in err and "--reducer" in err
    code = main(["analyze", str(path), "--reducer", "RV-999"])
    _, err = capsys.readouterr()
    assert code == 2 and "unknown reducer 'RV-999'" in err


def test_non_finite_value(capsys, tmp_path, csv_file):
    path, _ = csv_file
    lines = path.read_text().splitlines()
    fields = lines[30].split(",")
    fields[2] = "nan"
    lines[30] = ",".join(fields)
    assert_one_line_error(capsys, write_text(tmp_path, "\n".join(lines) + "\n"),
                          "non-finite value", "angle_arcsec", "line 31")

"""`tcms run` on the simulated bench: recovers the simulated truth; --out + `tcms analyze` give the same numbers."""

from __future__ import annotations

import json

import pytest

from tcms_daq.cli import main
from tcms_daq.samples import read_csv


def _run_json(capsys, *argv: str) -> dict:
    assert main(["run", *argv, "--json"]) == 0
    out, err = capsys.readouterr()
    assert err == ""  # no progress bar when stderr is not a terminal
    return json.loads(out)


def test_run_rv110e_recovers_truth(capsys):
    res = _run_json(capsys, "--reducer", "RV-110E")
    truth = res["truth"]
    assert truth["rigidity_nm_per_arcmin"] == pytest.approx(294.0, rel=1e-9)
    assert truth["backlash_arcsec"] == pytest.approx(25.15, rel=1e-9)
    assert res["rigidity_nm_per_arcmin"] == pytest.approx(truth["rigidity_nm_per_arcmin"], rel=0.01)
    assert res["backlash_arcsec"] == pytest.approx(truth["backlash_arcsec"], abs=1.0)
    assert res["lost_motion_arcsec"] == pytest.approx(truth["lost_motion_arcsec"], abs=1.0)
    assert res["loops"] and len([lp for lp in res["loops"] if lp["evaluated"]]) == 3
    assert set(res["per_direction"]) == {"positive", "negative"}
    assert res["profile"]["kind"] == "continuous" and res["profile"]["rate_nm_per_s"] == pytest.approx(269.5)
    assert res["verdict"]["passed"] is True


def test_same_seed_same_result_other_seed_differs(capsys):
    a = _run_json(capsys, "--reducer", "RV-60N", "--cycles", "1", "--seed", "5")
    b = _run_json(capsys, "--reducer", "RV-60N", "--cycles", "1", "--seed", "5")
    c = _run_json(capsys, "--reducer", "RV-60N", "--cycles", "1", "--seed", "6")
    assert a == b
    assert a["rigidity_nm_per_arcmin"] != c["rigidity_nm_per_arcmin"]


def test_out_then_analyze_gives_the_same_numbers(tmp_path, capsys):
    path = tmp_path / "x.csv"
    res = _run_json(capsys, "--out", str(path), "--cycles", "2", "--seed", "3")
    samples = read_csv(path)
    assert {"encoder_arcsec", "applied_torque_nm", "true_angle_arcsec", "loop_index"} <= set(samples.extra)
    assert set(samples.extra["loop_index"]) == {1.0, 2.0}
    assert main(["analyze", str(path), "--rated-torque", "1078", "--json"]) == 0
    again = json.loads(capsys.readouterr().out)
    for key in ("rigidity_nm_per_arcmin", "lost_motion_arcsec", "backlash_arcsec", "loading_rate_nm_per_s"):
        assert again[key] == res[key], key
    assert again["per_direction"] == res["per_direction"]


def test_table_output_and_stepped_harmonic_drive(capsys):
    argv = ["run", "--reducer", "HFUC-32-100", "--profile", "stepped", "--step", "20", "--dwell", "0.2",
            "--cycles", "1", "--rate", "100"]
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "HFUC-32-100, stepped profile ±137 N·m" in out
    assert "K1 [Nm/rad]" in out and "simulated truth: rigidity" in out


def test_run_harmonic_drive_recovers_truth(capsys):
    res = _run_json(capsys, "--reducer", "HFUC-32-100", "--cycles", "2")
    truth = res["truth"]
    assert res["rigidity_nm_per_arcmin"] == pytest.approx(truth["rigidity_nm_per_arcmin"], rel=0.01)
    assert res["backlash_arcsec"] == pytest.approx(truth["backlash_arcsec"], abs=1.0)
    for key in ("k1_nm_per_rad", "k2_nm_per_rad", "k3_nm_per_rad"):
        assert res[key] == pytest.approx(truth[key], rel=0.02), key


def test_run_with_smaller_torque(capsys):
    res = _run_json(capsys, "--reducer", "RV-100C", "--max-torque", "600", "--cycles", "1", "--rate", "600")
    assert res["test_torque_nm"] == 600.0 and res["truth"]["test_torque_nm"] == 600.0
    assert res["rigidity_nm_per_arcmin"] == pytest.approx(res["truth"]["rigidity_nm_per_arcmin"], rel=0.01)


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--reducer", "RV-999X"], "unknown reducer 'RV-999X'"),
        (["--max-torque", "2500"], "exceeds the bench limit 2000 N·m"),
        (["--config", "/nonexistent/bench.toml"], "/nonexistent/bench.toml: no such file"),
        (["--profile", "stepped", "--dwell", "-1"], "--dwell must be >= 0 s"),
        (["--out", "/nonexistent/dir/x.csv", "--cycles", "1"], "/nonexistent/dir/x.csv: cannot write"),
    ],
)
def test_run_errors_are_one_line(capsys, argv, message):
    assert main(["run", *argv]) == 2
    err = capsys.readouterr().err
    assert err.startswith("tcms: error: ") and message in err and err.count("\n") == 1


def test_run_bad_config_value(tmp_path, capsys, bench_text):
    path = tmp_path / "bench.toml"
    path.write_text(bench_text.replace("torque_noise_nm = 0.3", "torque_noise_nm = -0.3"), encoding="utf-8")
    assert main(["run", "--config", str(path)]) == 2
    err = capsys.readouterr().err
    assert str(path) in err and "sim.torque_noise_nm" in err and "greater than or equal to 0" in err


@pytest.mark.parametrize("argv", [["--cycles", "0"], ["--max-torque", "-5"], ["--seed", "x"]])
def test_run_rejects_bad_options(capsys, argv):
    with pytest.raises(SystemExit) as exc:
        main(["run", *argv])
    assert exc.value.code == 2
    assert "error:" in capsys.readouterr().err


def test_progress_bar_only_on_a_terminal():
    import fcntl
    import os
    import pty
    import select
    import struct
    import subprocess
    import sys
    import termios

    master, slave = pty.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 40, 120, 0, 0))
    cmd = [sys.executable, "-m", "tcms_daq.cli", "run", "--cycles", "1", "--json"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=slave)
    os.close(slave)
    err = b""
    while select.select([master], [], [], 60)[0]:
        try:
            chunk = os.read(master, 65536)
        except OSError:
            break
        if not chunk:
            break
        err += chunk
    out = proc.stdout.read()
    assert proc.wait(timeout=60) == 0
    os.close(master)
    assert b"RV-110E (test time)" in err and b"(real time)" in err and b"100%" in err and b"loop 1/1" in err
    assert json.loads(out)["n_loops"] == 1  # stdout stays one JSON object

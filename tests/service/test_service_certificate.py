"""The PDF certificate names the serial number and the results with U (read back with pdftotext), the decision
rule, the verdict, the calibration and the compensation; old results say "U not stated"; typed text stays text."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys

import numpy as np
import pytest
from svc_helpers import ScriptedRunner, results_with_uncertainty, serve, wait_for

from tcms_daq.store import RunStore, open_store

RIGIDITY = "293.9 ± 2.3 N·m/arcmin (k = 2.05)"
LOST_MOTION = "41.27 ± 0.82″ (k = 2.00)"
BACKLASH = "18.6 ± 1.2″ (k = 2.00)"
CHANNELS = ("time_s", "torque_nm", "angle_arcsec", "encoder_arcsec")


def pdf_text(pdf: bytes) -> str:
    """The PDF's text by poppler's pdftotext, whitespace runs folded to one space."""
    if shutil.which("pdftotext") is None:
        if shutil.which("apt-get"):
            pytest.fail("pdftotext not found: run `bash scripts/setup` (it installs poppler-utils)")
        pytest.skip("no pdftotext (poppler-utils) and no Debian package manager to install it")
    assert pdf.startswith(b"%PDF-")
    out = subprocess.run(["pdftotext", "-layout", "-", "-"], input=pdf, capture_output=True, check=True).stdout
    return re.sub(r"\s+", " ", out.decode("utf-8"))


def test_certificate_pdf_names_serial_number_results_with_u_and_verdict(settings_factory):
    runner = ScriptedRunner(bench_name="Line 3 bench", bench_id="line-3", speed=50.0,
                            results=results_with_uncertainty("undecided"))
    with serve(settings_factory(), runner=runner) as server:
        c = server.client()
        run_id = c.post("/api/tests", json={"reducer": "RV-110E", "max_torque_nm": 200, "cycles": 1,
                                            "rate_nm_per_s": 400, "serial_number": "SN-4711",
                                            "operator": "Ada Lovelace"}).json()["id"]
        wait_for(lambda: c.get(f"/api/tests/{run_id}").json()["status"] == "completed", timeout_s=60)
        r = c.get(f"/api/tests/{run_id}/certificate.pdf")
        assert r.status_code == 200 and r.headers["content-type"] == "application/pdf"
        assert c.get("/api/tests/nope/certificate.pdf").status_code == 404
    text = pdf_text(r.content)
    for expected in (f"Certificate {run_id} · issued", "Serial number SN-4711", "Reducer RV-110E", "Operator Ada Lovelace",
                     "Bench Line 3 bench (id line-3)", "Test torque 200 N·m", "Torque rate 400 N·m/s",
                     f"torsional rigidity {RIGIDITY} torque scale", f"lost motion {LOST_MOTION}",
                     f"backlash {BACKLASH}", "Decision rule: guarded acceptance (ISO 14253-1)",
                     "lost motion ≤ 60 arcsec 41.27 0.82 undecided", "Verdict: UNDECIDED",
                     "Basis: declared chain: bench config", "Version the bench configuration's file"):
        assert expected in text, expected


@pytest.fixture
def stored_runs(tmp_path):
    """A SQLite store with a completed run (calibration in its config, a compensation version, markup in its
    typed fields) and an old run without uncertainty keys."""
    data_dir = tmp_path / "data"
    with open_store(None, data_dir, bench_id="line-7", bench_name="Line 7") as store:
        version = store.add_compensation("[compensator]\nterms = []\n", note="calibrated")
        snapshot = {"bench": {"name": "Line 7"}, "instruments": {
            "angle": {"driver": "nd287", "url": "socket://127.0.0.1:4001", "calibration": {
                "device": "RON 786 #55", "certificate": "K-0815", "laboratory": "Cal Lab", "calibrated_on": "2026-02-03",
                "due": "2027-02-03", "uncertainty": "0.4 arcsec (k = 2)"}},
            "torque": {"driver": "aed", "url": "socket://127.0.0.1:4002"}}}
        t = np.linspace(0.0, 20.0, 2000)
        torque = 300.0 * np.sin(2 * np.pi * t / 10.0)
        angle = torque / 200.0 * 60.0 + 12.0 * np.sign(np.cos(2 * np.pi * t / 10.0))
        for run_id, serial, results in (
                ("new", "#set text(red) *SN* $x$ <a> @b", results_with_uncertainty("fail")),
                ("old", "SN-OLD-1", {"rigidity_nm_per_arcmin": 201.5, "backlash_arcsec": 24.0,
                                     "verdict": {"passed": True, "checks": {}}})):
            store.create_run(run_id, {"reducer": "RV-60N", "max_torque_nm": 300.0, "cycles": 2,
                                      "serial_number": serial, "operator": "O'Neil & Sons"}, CHANNELS,
                             config_snapshot=snapshot, compensator_toml="[compensator]\nterms = []\n",
                             compensation_version=version.version)
            store.append_samples(run_id, [{"time_s": t, "torque_nm": torque, "angle_arcsec": angle,
                                           "encoder_arcsec": angle}])
            store.set_status(run_id, "running")
            store.set_status(run_id, "completed", results=results)
    return data_dir, version.version


def _cli(*args: str, cwd) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "tcms_daq.cli", "certificate", *args], capture_output=True,
                          text=True, cwd=cwd, timeout=120)


def test_certificate_cli_from_another_directory(stored_runs, tmp_path):
    data_dir, version = stored_runs
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    done = _cli("new", "--data-dir", str(data_dir), cwd=elsewhere)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "wrote tcms-certificate-new.pdf (certificate of run new, completed)"
    text = pdf_text((elsewhere / "tcms-certificate-new.pdf").read_bytes())
    for expected in ("#set text(red) *SN* $x$ <a> @b", "O'Neil & Sons", RIGIDITY, "Verdict: FAIL",
                     "RON 786 #55 (nd287 at socket://127.0.0.1:4001)", "certificate K-0815, by Cal Lab, calibrated "
                     "2026-02-03, due 2027-02-03, U = 0.4 arcsec (k = 2)", "not stated in the bench configuration",
                     f"Version {version} (accepted upload)", "Bench Line 7 (id line-7)"):
        assert expected in text, expected

    out = tmp_path / "old.pdf"
    assert _cli("old", "--data-dir", str(data_dir), "-o", str(out), cwd=elsewhere).returncode == 0
    old = pdf_text(out.read_bytes())
    assert "Serial number SN-OLD-1" in old and "torsional rigidity 201.5 N·m/arcmin (U not stated)" in old
    assert "backlash 24″ (U not stated)" in old and "lost motion — U not stated" in old
    assert "simple acceptance" in old and "Verdict: PASS" in old

    for args, message in ((("nope", "--data-dir", str(data_dir)), "unknown run 'nope'"),
                          (("new", "--data-dir", str(tmp_path / "none")), "no run store at"),
                          (("new", "--data-dir", str(data_dir), "-o", str(tmp_path / "no" / "x.pdf")), "cannot write"),
                          (("new", "--store", "ftp://x"), "unknown scheme")):
        bad = _cli(*args, cwd=elsewhere)
        assert bad.returncode == 2 and bad.stderr.startswith("tcms: error: ") and message in bad.stderr
        assert bad.stderr.count("\n") == 1


def test_certificate_of_a_run_on_postgres(stored_runs, postgres_url, tmp_path):
    """The CLI reads a PostgreSQL store too (the run copied over from the SQLite one)."""
    data_dir, _ = stored_runs
    with RunStore(data_dir / "tcms-runs.sqlite3", recover=False) as src, \
            open_store(postgres_url, tmp_path, bench_id="line-7", bench_name="Line 7") as dst:
        rec = src.get_run("new")
        dst.create_run("new", rec.request, rec.channels, config_snapshot=rec.config_snapshot,
                       compensator_toml=rec.compensator_toml)
        dst.append_samples("new", [src.read_columns("new")])
        dst.set_status("new", "completed", results=rec.results)
    out = tmp_path / "pg.pdf"
    done = _cli("new", "--store", postgres_url, "-o", str(out), cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert LOST_MOTION in pdf_text(out.read_bytes())

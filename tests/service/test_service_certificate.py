"""The PDF certificate names the serial number and the results with U (read back with pdftotext), the decision
rule, the verdict, the calibration and the compensation; old results say "U not stated"; typed text stays text."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from svc_helpers import ScriptedRunner, results_with_uncertainty, serve, wait_for

from tcms_daq.analysis.rounding import round_to_uncertainty
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
    for expected in (f"Certificate {run_id} · issued", "Serial number SN-4711", "Reducer (model) RV-110E",
                     "Tested by Ada Lovelace", "Customer not stated", "Test bench Line 3 bench (id line-3)",
                     "Test method GB/T 35089-2018", "Ambient temperature not recorded", "Test torque 200 N·m",
                     "Torque rate 400 N·m/s", f"Torsional rigidity {RIGIDITY} torque scale", f"Lost motion {LOST_MOTION}",
                     f"Backlash {BACKLASH}", "Decision rule: guarded acceptance (ISO 14253-1)",
                     "lost motion ≤ 60 arcsec 41.27 0.82 undecided", "Verdict: UNDECIDED",
                     "Basis of the evaluation: declared chain: bench config.", "Compensation version 1",
                     "The results are the mean over the evaluated loops.", "Traceability:", "Approved by"):
        assert expected in text, expected
    assert "loop energy" not in text and "0.306101" not in text


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
                ("new", "#set text(red) *SN* $x$ <a> @b",
                 {**results_with_uncertainty("fail"),
                  "uncertainty_basis": "declared chain: bench config /opt/bench/configs/bench-line-7.toml"}),
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
                     "RON 786 #55 (nd287)", "certificate K-0815, by Cal Lab, calibrated 2026-02-03, due "
                     "2027-02-03, U = 0.4 arcsec (k = 2)", "not stated in the bench configuration",
                     f"Compensation version {version}", "Test bench Line 7 (id line-7)",
                     "Basis of the evaluation: declared chain: bench config bench-line-7.toml."):
        assert expected in text, expected
    assert "/opt/bench" not in text and "socket://" not in text  # no path or address of the bench PC

    out = tmp_path / "old.pdf"
    assert _cli("old", "--data-dir", str(data_dir), "-o", str(out), cwd=elsewhere).returncode == 0
    old = pdf_text(out.read_bytes())
    assert "Serial number SN-OLD-1" in old and "Torsional rigidity 201.5 N·m/arcmin (U not stated)" in old
    assert "Backlash 24″ (U not stated)" in old and "Lost motion — U not stated" in old
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


def _plant_config(tmp_path):
    """The simulated bench with the richer reducer model (each output position differs), the issuing laboratory,
    the room's temperature and calibrated instruments: what a plant's bench configuration states."""
    import tomllib

    import tomli_w

    from tcms_daq.config import default_bench_config_path, packaged_config_dir

    config = tomllib.loads(default_bench_config_path().read_text(encoding="utf-8"))
    here = packaged_config_dir()
    config["bench"].update(compensation=str(here / "geometry-sim.toml"), reducers=str(here / "reducers.toml"),
                           id="line-2", name="Line 2 torsion bench", manufacturer="TCMS", model="TB-2000",
                           serial_number="TB-0007")
    config["sim"].update(geometry=str(here / "geometry-sim.toml"), model="rich")
    config["certificate"] = {"laboratory": "Reducer test laboratory, Plant 3, Suzhou", "ambient_temperature_c": 20.0}
    config["instruments"]["angle"]["calibration"] = {
        "device": "Heidenhain RON 786 #38411", "certificate": "K-2026-0815", "laboratory": "DKD-K-01201",
        "calibrated_on": "2026-03-02", "due": "2027-03-02", "uncertainty": "0.4 arcsec (k = 2)"}
    config["instruments"]["torque"]["calibration"] = {
        "device": "HBM T40B 2 kN·m #112", "certificate": "D-K-15183-2026-04", "laboratory": "HBM DAkkS lab",
        "calibrated_on": "2026-04-14", "due": "2027-04-14", "uncertainty": "0.05 % of reading (k = 2)"}
    path = tmp_path / "bench-line-2.toml"
    path.write_bytes(tomli_w.dumps(config).encode("utf-8"))
    return path


def _pixels(png: Path, rgb: tuple[int, int, int], tolerance: int = 40) -> int:
    """How many pixels of a rendered page are within ``tolerance`` of the colour ``rgb``."""
    from matplotlib.image import imread

    image = imread(png)[..., :3] * 255.0
    return int(np.count_nonzero(np.all(np.abs(image - np.asarray(rgb)) <= tolerance, axis=-1)))


@pytest.mark.timeout(300)
def test_certificate_of_a_four_position_test_has_the_per_position_table_and_a_readable_loop(settings_factory,
                                                                                            tmp_path):
    from tcms_daq.service.loop_figure import relative_loops

    settings = settings_factory(config_path=_plant_config(tmp_path), sim_speed=50.0)
    with serve(settings) as server:
        c = server.client()
        run_id = c.post("/api/tests", json={
            "reducer": "RV-110E", "max_torque_nm": 300, "cycles": 2, "rate_nm_per_s": 300, "positions": 4,
            "serial_number": "SN-2026-0042", "operator": "Li Wei", "customer": "ACME Robotics GmbH",
            "order_number": "PO-4711"}).json()["id"]
        run = wait_for(lambda: (r := c.get(f"/api/tests/{run_id}").json())["status"] in
                       ("completed", "failed", "aborted") and r, timeout_s=240)
        assert run["status"] == "completed", run["error"]
        pdf = c.get(f"/api/tests/{run_id}/certificate.pdf").content
        record = server.app.state.store.get_run(run_id)
        columns = server.app.state.store.read_columns(run_id)
    text = pdf_text(pdf)
    results = run["results"]
    for expected in ("Customer ACME Robotics GmbH", "Order number PO-4711", "Serial number SN-2026-0042",
                     "Test method GB/T 40731-2021, at several output", "Test bench Line 2 torsion bench (id",
                     "TB-2000 TB-0007", "Ambient temperature 20 °C (test room", "Tested by Li Wei",
                     "Output positions 0, 90, 180, 270°", "Issued by: Reducer test laboratory, Plant 3, Suzhou",
                     "The results are the worst of the 4 output positions", "Results at each output position",
                     "Position / ° Rigidity / N·m/arcmin Lost motion / arcsec Backlash / arcsec",
                     "Result: worst of 4", "Spread (largest − smallest)", "Heidenhain RON 786 #38411 (virtual)",
                     "certificate K-2026-0815, by DKD-K-01201", "Compensation version 1", "Bench model version 0"):
        assert expected in text, expected
    for stage in results["positions"]:  # each position's row: its angle and its results rounded to their U
        entry = stage["uncertainty"]["lost_motion_arcsec"]
        cell = " ± ".join(round_to_uncertainty(stage["lost_motion_arcsec"], entry["U"]))
        assert f"{stage['position_deg']:g} " in text and cell in text, (stage["position_deg"], cell)
    worst = max(s["lost_motion_arcsec"] for s in results["positions"])
    assert results["lost_motion_arcsec"] == worst

    # the loop in relative twist: each position's loops about their own centre span about ±T/R, although the
    # output stood 90° (5400 arcmin) apart
    loops = relative_loops(columns, record.results)
    assert [stage for stage, _, _ in loops] == [1, 2, 3, 4]
    span_arcmin = 300.0 / results["rigidity_nm_per_arcmin"]
    for _, torque, twist in loops:
        assert np.ptp(columns["angle_arcsec"]) / 60.0 > 100 * span_arcmin
        assert 1.6 * span_arcmin < np.ptp(twist) < 2.6 * span_arcmin
        assert abs(float(np.median(twist[np.abs(torque) < 5.0]))) < 0.2 * span_arcmin  # centred at zero torque
    page = tmp_path / "page"
    subprocess.run(["pdftoppm", "-r", "110", "-f", "1", "-l", "1", "-png", "-singlefile", "-", str(page)],
                   input=pdf, check=True)
    for colour in ((31, 95, 168), (217, 119, 30)):  # the first and second positions' loops are drawn
        assert _pixels(page.with_suffix(".png"), colour) > 150
    if os.environ.get("TCMS_UPDATE_SCREENSHOT"):
        shutil.copyfile(page.with_suffix(".png"), Path(__file__).parents[2] / "docs" / "certificate-positions.png")


def test_every_word_of_the_certificate_comes_from_the_catalogue(stored_runs, monkeypatch):
    """A catalogue whose every entry is a marker leaves no English of its own on the page: the template and the
    code print only the catalogue's words and the run's data."""
    from tcms_daq.service import certificate_text
    from tcms_daq.service.certificate import render_certificate

    fields = re.compile(r"\{(\w+)\}")
    markers = {key: f"@{i}@" + "".join(f" {{{f}}}" for f in fields.findall(value))
               for i, (key, value) in enumerate(certificate_text.EN.items())}
    monkeypatch.setitem(certificate_text.CATALOGUES, "xx", markers)
    data_dir, _ = stored_runs
    with RunStore(data_dir / "tcms-runs.sqlite3", recover=False) as store:
        record, columns = store.get_run("new"), store.read_columns("new")
    text = pdf_text(render_certificate(record, columns, lang="xx"))
    assert "@0@" in text and "@5@" in text
    # (the run's own data stay as recorded: its serial number, the check labels and the budget's source names)
    for word in ("Certificate", "certificate", "Customer", "Serial", "Verdict", "Decision", "Result", "Torsional",
                 "Approved", "Signature", "page", "UTC", "Traceability", "Basis", "not stated", "GB/T", "SI"):
        assert word not in text, word


def test_the_loop_centre_is_the_midline_at_zero_torque():
    """Generated loops (a spring with a friction band of known width and an offset): the centre is the offset,
    whether the band is symmetric or the two branches differ in stiffness."""
    from tcms_daq.service.loop_figure import loop_centre_arcsec

    t = np.linspace(0.0, 40.0, 8000)
    torque = 300.0 * np.sin(2 * np.pi * t / 10.0)
    rising = np.cos(2 * np.pi * t / 10.0) > 0
    rng = np.random.default_rng(3)
    for offset, width, stiff_up in ((16_200.0, 12.0, 1.0), (-5.0, 30.0, 1.3), (720.0, 0.0, 1.0)):
        compliance = np.where(rising, 60.0 / 294.0 / stiff_up, 60.0 / 294.0)
        angle = offset + compliance * torque + np.where(rising, -width / 2, width / 2) + rng.normal(0, 0.2, t.size)
        assert abs(loop_centre_arcsec(torque, angle) - offset) < 0.3, (offset, width)


def test_paths_of_the_bench_pc_are_left_out():
    from tcms_daq.service.certificate import without_paths

    assert without_paths("declared chain: bench config /home/bench/cfg/bench-sim.toml") == \
        "declared chain: bench config bench-sim.toml"
    assert without_paths(r"type A only (no uncertainty declared in C:\bench\cfg\a.toml)") == \
        "type A only (no uncertainty declared in a.toml)"
    kept = "rigidity 294 N·m/arcmin at socket://127.0.0.1:4001, 2/3 of T"
    assert without_paths(kept) == kept

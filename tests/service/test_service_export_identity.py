"""Exports carry the test's identity and results ± U, and start at the test's start (read back with asammdf and
pyarrow); the CSV stays canonical with its identity in a sidecar JSON. A run without uncertainty keys renders
"U not stated"."""

from __future__ import annotations

import io
import json
from datetime import UTC, datetime

import numpy as np
import pyarrow.parquet as pq
import pytest
from svc_helpers import ScriptedRunner, results_with_uncertainty, serve, wait_for

from tcms_daq.samples import parse_csv_text

REQUEST = {"reducer": "RV-110E", "max_torque_nm": 200, "cycles": 1, "rate_nm_per_s": 400,
           "serial_number": "SN-4711", "operator": "Ada Lovelace", "customer": "ACME Robotics",
           "order_number": "PO-88"}
# the renderings the contract asks for, written out by hand from the injected numbers
RIGIDITY = "293.9 ± 2.3 N·m/arcmin (k = 2.05)"
LOST_MOTION = "41.27 ± 0.82″ (k = 2.00)"
BACKLASH = "18.6 ± 1.2″ (k = 2.00)"


@pytest.fixture
def finished(settings_factory):
    """A service with a completed run whose results carry U (and one without), via HTTP."""
    runner = ScriptedRunner(bench_name="Line 3 bench", bench_id="line-3", speed=50.0,
                            results=results_with_uncertainty())
    with serve(settings_factory(), runner=runner) as server:
        c = server.client()
        run_id = c.post("/api/tests", json=REQUEST).json()["id"]
        wait_for(lambda: c.get(f"/api/tests/{run_id}").json()["status"] == "completed", timeout_s=60)
        runner.results = {"rigidity_nm_per_arcmin": 301.5, "verdict": {"passed": True, "checks": {}}}
        plain_id = c.post("/api/tests", json={**REQUEST, "serial_number": "SN-OLD"}).json()["id"]
        wait_for(lambda: c.get(f"/api/tests/{plain_id}").json()["status"] == "completed", timeout_s=60)
        yield c, run_id, plain_id


def _started(c, run_id) -> datetime:
    return datetime.fromisoformat(c.get(f"/api/tests/{run_id}").json()["started_at"])


def test_mdf4_header_and_channels_carry_identity_and_start_at_the_test_start(finished):
    from asammdf import MDF

    c, run_id, _ = finished
    body = c.get(f"/api/tests/{run_id}/samples", params={"format": "mdf4"}).content
    mdf = MDF(io.BytesIO(body))
    try:
        header = mdf.header
        assert header.author == "Ada Lovelace" and header.department == "Line 3 bench"
        assert header.project == "TCMS-DAQ torsional characteristic test"
        assert header.subject == "RV-110E serial number SN-4711"
        text = header.description
        for expected in ("SN-4711", "Line 3 bench (id line-3)", "operator Ada Lovelace", "test torque 200 N·m",
                         "torque rate 400 N·m/s", "customer ACME Robotics, order PO-88",
                         "compensation: version 1, sha256 ", "bench model version 0", RIGIDITY, LOST_MOTION,
                         BACKLASH, "verdict: pass"):
            assert expected in text, expected
        tree = header._common_properties["tcms"]
        assert tree["serial_number"] == "SN-4711" and tree["bench_id"] == "line-3" and tree["verdict"] == "pass"
        assert tree["compensation_version"] == "1" and len(tree["compensation_sha256"]) == 64
        assert tree["bench_model_version"] == "0" and tree["method"] == "single"
        assert json.loads(tree["results"])["rigidity_nm_per_arcmin"]["U"] == pytest.approx(2.3)
        # the header's start is the test's start (to the microsecond MDF keeps), not the download's
        assert abs((header.start_time - _started(c, run_id)).total_seconds()) < 1e-3
        torque = mdf.get("torque_nm")
        assert torque.timestamps[0] == 0.0 and "SN-4711" in torque.comment and RIGIDITY in torque.comment
        assert "compensated twist angle" in mdf.get("angle_arcsec").comment
        csv = parse_csv_text(c.get(f"/api/tests/{run_id}/samples?format=csv").text)
        np.testing.assert_allclose(torque.timestamps, csv["time_s"] - csv["time_s"][0], atol=1e-9)
        np.testing.assert_array_equal(torque.samples, csv["torque_nm"])
    finally:
        mdf.close()


def test_parquet_schema_metadata_carries_identity_results_and_start(finished):
    c, run_id, _ = finished
    table = pq.read_table(io.BytesIO(c.get(f"/api/tests/{run_id}/samples", params={"format": "parquet"}).content))
    md = {k.decode(): v.decode() for k, v in table.schema.metadata.items()}
    assert md["run_id"] == run_id and md["serial_number"] == "SN-4711" and md["reducer"] == "RV-110E"
    assert md["bench_id"] == "line-3" and md["bench_name"] == "Line 3 bench" and md["operator"] == "Ada Lovelace"
    # the bench configuration's compensation is kept as version 1 on the service's first start
    assert md["verdict"] == "pass" and md["compensation_version"] == "1" and md["bench_model_version"] == "0"
    assert md["customer"] == "ACME Robotics" and md["order_number"] == "PO-88" and md["method"] == "single"
    assert json.loads(md["parameters"]) == {"max_torque_nm": 200.0, "cycles": 1, "profile": "continuous",
                                            "rate_nm_per_s": 400.0}
    results = json.loads(md["results"])
    assert results["rigidity_nm_per_arcmin"]["text"] == RIGIDITY and results["backlash_arcsec"]["text"] == BACKLASH
    doc = json.loads(md["tcms"])
    assert doc["results"]["uncertainty"]["lost_motion_arcsec"]["U"] == pytest.approx(0.82)
    assert datetime.fromisoformat(md["start_time"]) == _started(c, run_id)
    assert float(md["time_s_at_start"]) == table.column("time_s").to_numpy()[0]
    assert table.schema.field("torque_nm").metadata == {b"unit": "N·m".encode(), b"description": b"measured torque"}


def test_csv_stays_canonical_with_a_sidecar_and_old_results_say_u_not_stated(finished):
    c, run_id, plain_id = finished
    r = c.get(f"/api/tests/{run_id}/samples", params={"format": "csv"})
    assert r.text.startswith("time_s,torque_nm,angle_arcsec,encoder_arcsec\n")  # `tcms analyze` reads it as before
    assert parse_csv_text(r.text)["time_s"].size == c.get(f"/api/tests/{run_id}").json()["sample_count"]
    assert r.headers["Link"] == f'</api/tests/{run_id}/metadata>; rel="describedby"; type="application/json"'
    side = c.get(f"/api/tests/{run_id}/metadata").json()
    assert side["identity"]["serial_number"] == "SN-4711" and side["identity"]["results"]["lost_motion_arcsec"][
        "text"] == LOST_MOTION
    assert side["identity"]["compensation_version"] == 1 and side["identity"]["method"]["kind"] == "single"
    assert side["time_s_at_start"] == parse_csv_text(r.text)["time_s"][0]
    assert datetime.fromisoformat(side["start_time"]) == _started(c, run_id)

    old = c.get(f"/api/tests/{plain_id}/metadata").json()["identity"]
    assert old["results"]["rigidity_nm_per_arcmin"]["text"] == "301.5 N·m/arcmin (U not stated)"
    assert old["results"]["backlash_arcsec"]["text"] == "—" and old["verdict"] == "pass"
    md = pq.read_table(io.BytesIO(c.get(f"/api/tests/{plain_id}/samples?format=parquet").content)).schema.metadata
    assert "U not stated" in md[b"results"].decode()
    assert datetime.now(UTC) > _started(c, plain_id)

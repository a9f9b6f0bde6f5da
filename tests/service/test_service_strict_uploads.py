"""Strict compensation uploads through the service (issue 22): the uploads that passed silently wrong are 422 with
a one-line reason and change nothing; an upload that changes the rigidity of the reference record beyond the band
is refused unless forced; a dry run shows the change and stores nothing. The real runner, simulated bench."""

from __future__ import annotations

import pytest
from svc_helpers import TOKEN, serve, wait_for

TORSION = '[[terms]]\ntype = "torsion"\narcsec_per_nm = {}\n'
ISSUE_CASES = [
    ('[[compensator.terms]]\ntype = "scale"\ncoefficient = 0.5\n', "unknown key 'terms'"),
    (TORSION.format("1e6"), "torsion: arcsec_per_nm 1e+06"),
    (TORSION.format("-0.9"), "torsion: arcsec_per_nm -0.9"),
    ("".join(f'[[terms]]\ntype = "periodic"\nperiod_arcsec = {72.0 / (k + 1):.9g}\nsin_arcsec = 0.5\n'
             for k in range(10_000)), "10000 terms"),
]


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    from tcms_daq.config.loader import default_bench_config_path
    from tcms_daq.service.app import ServiceSettings

    settings = ServiceSettings(data_dir=tmp_path_factory.mktemp("data"), api_token=TOKEN,
                               config_path=default_bench_config_path(), sim_speed=1000.0,
                               max_body_bytes=2 * 1024 * 1024)
    with serve(settings) as srv:
        yield srv


@pytest.mark.parametrize(("toml", "named"), ISSUE_CASES, ids=["compensator.terms", "torsion-1e6", "torsion-0.9",
                                                              "10000-periodic"])
def test_the_uploads_of_the_issue_are_422_with_one_line_and_change_nothing(server, toml, named):
    with server.client() as c:
        before = c.get("/api/compensation").text
        versions = len(c.get("/api/compensation/history").json())
        for params in ({}, {"force": "true"}, {"dry_run": "true"}):  # neither force nor a dry run lets them by
            r = c.put("/api/compensation", params=params, content=toml.encode())
            assert r.status_code == 422, r.text
            detail = r.json()["detail"]
            assert named in detail and "\n" not in detail and len(detail) < 400, detail
        assert c.get("/api/compensation").text == before
        assert len(c.get("/api/compensation/history").json()) == versions


def test_a_rigidity_change_beyond_the_band_needs_force_and_a_dry_run_stores_nothing(server):
    scale = '[[terms]]\ntype = "scale"\ncoefficient = 0.08\n'  # within the scale band, +8 % or so of rigidity
    with server.client() as c:
        before = c.get("/api/compensation").text
        versions = len(c.get("/api/compensation/history").json())
        dry = c.put("/api/compensation", params={"dry_run": "true"}, content=scale.encode())
        assert dry.status_code == 202, dry.text
        shown = dry.json()
        assert shown["rigidity_change_pct"] > 5.0 and "force=true" in shown["refused"]
        assert shown["reference"]
        refused = c.put("/api/compensation", content=scale.encode())
        assert refused.status_code == 422 and "force=true" in refused.json()["detail"]
        assert c.get("/api/compensation").text == before
        assert len(c.get("/api/compensation/history").json()) == versions
        forced = c.put("/api/compensation", params={"force": "true", "note": "forced"}, content=scale.encode())
        assert forced.status_code == 200 and "scale" in forced.text
        assert len(c.get("/api/compensation/history").json()) == versions + 1
        # going back is within the band of the new state only when forced as well: roll back instead
        assert c.post(f"/api/compensation/rollback/{versions}").status_code == 200


def test_the_reference_is_the_last_completed_run(server):
    with server.client() as c:
        run_id = c.post("/api/tests", json={"reducer": "RV-110E", "max_torque_nm": 500, "cycles": 1,
                                            "rate_nm_per_s": 500}).json()["id"]
        done = wait_for(lambda: (r := c.get(f"/api/tests/{run_id}").json())["status"] in
                        ("completed", "failed", "aborted") and r, timeout_s=300)
        assert done["status"] == "completed", done
        current = c.get("/api/compensation").text
        dry = c.put("/api/compensation", params={"dry_run": "true"}, content=current.encode())
        assert dry.status_code == 202 and run_id in dry.json()["reference"]
        assert dry.json()["rigidity_change_pct"] == pytest.approx(0.0, abs=1e-6) and dry.json()["refused"] is None

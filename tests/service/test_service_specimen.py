"""The requested specimen: on the simulated bench the physics follows the reducer of the request, so the service
measures what `tcms run --reducer` measures; the verdict judges rigidity against the catalogue (issue 10)."""

from __future__ import annotations

import json

import pytest
from svc_helpers import TOKEN, serve, wait_for

from tcms_daq.analysis import Limits
from tcms_daq.cli import main
from tcms_daq.config import load_reducer_catalogue

REQUEST = {"reducer": "HFUC-32-100", "max_torque_nm": 100, "cycles": 1, "rate_nm_per_s": 100}


def test_the_service_measures_the_requested_reducer_like_the_cli(tmp_path, capsys):
    from tcms_daq.config.loader import default_bench_config_path
    from tcms_daq.service.app import ServiceSettings

    assert main(["run", "--reducer", "HFUC-32-100", "--max-torque", "100", "--rate", "100", "--cycles", "1",
                 "--json"]) == 0
    cli = json.loads(capsys.readouterr().out)
    settings = ServiceSettings(data_dir=tmp_path / "data", api_token=TOKEN, config_path=default_bench_config_path(),
                               sim_speed=1000.0)
    with serve(settings) as srv, srv.client() as c:
        run_id = c.post("/api/tests", json=REQUEST).json()["id"]
        done = wait_for(lambda: (r := c.get(f"/api/tests/{run_id}").json())["status"] in
                        ("completed", "failed", "aborted") and r, timeout_s=120)
    assert done["status"] == "completed", done
    served = done["results"]["rigidity_nm_per_arcmin"]
    # the config's [sim] reducer is the RV-110E (294 N·m/arcmin): the HFUC-32-100 is ~37
    assert served == pytest.approx(cli["rigidity_nm_per_arcmin"], rel=0.05)
    assert served < 60.0
    assert done["results"]["verdict"]["passed"] is True, done["results"]["verdict"]


def test_a_rigidity_outside_the_catalogue_tolerance_fails_the_verdict():
    spec = load_reducer_catalogue()["RV-110E"]
    limits = Limits(**spec.limits())
    ok = {"rigidity_nm_per_arcmin": 290.0, "backlash_arcsec": 20.0, "lost_motion_arcsec": 20.0}
    assert limits.judge(ok)["passed"]
    soft = limits.judge({**ok, "rigidity_nm_per_arcmin": 200.0})  # 32 % below the catalogue's 294
    assert not soft["passed"]
    assert soft["checks"]["rigidity_min_nm_per_arcmin"]["label"].startswith("rigidity ≥ 235.2 N·m/arcmin")
    assert not limits.judge({**ok, "rigidity_nm_per_arcmin": 589.7})["passed"]  # a halved scale: too stiff

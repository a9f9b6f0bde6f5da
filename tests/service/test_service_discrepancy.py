"""POST /api/discrepancy end to end: a test run on the in-process simulated bench (fast simulated clock), then
the discrepancy workflow on it over HTTP, against the bench model re-simulated on the run's torque trace."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

import numpy as np
import pytest
import tomli_w
from svc_helpers import serve, wait_for

from tcms_daq.cli import main
from tcms_daq.store import STORE_FILENAME, RunStore

REQUEST = {"reducer": "RV-110E", "max_torque_nm": 500, "cycles": 1, "profile": "continuous", "rate_nm_per_s": 250}
PER_ANALYSIS_KEYS = {"id", "created_at", "report_url"}  # each analysis its own; the rest is the same work


def _finished(c, run_id: str) -> dict:
    return wait_for(lambda: (t := c.get(f"/api/tests/{run_id}").json())["status"] not in ("queued", "running")
                    and t, timeout_s=60)


@pytest.mark.timeout(120)
def test_discrepancy_of_a_stored_run_over_http(settings_factory, sim_config, tmp_path, capsys):
    settings = settings_factory(config_path=sim_config, sim_speed=20.0)
    with RunStore(settings.data_dir / STORE_FILENAME) as store:  # a run that stopped after a few samples
        store.create_run("short-run", {"reducer": "RV-110E"}, ("time_s", "torque_nm", "angle_arcsec"),
                         status="aborted")
        store.append_samples("short-run", [{"time_s": np.arange(5) * 2e-3, "torque_nm": np.arange(5.0),
                                            "angle_arcsec": np.arange(5.0)}])

    with serve(settings) as srv, srv.client() as c, srv.client(None) as anon:
        run_id = c.post("/api/tests", json=REQUEST).json()["id"]
        # no analysis while a test runs (of that run or of any other): acquisition keeps the CPU
        for target in (run_id, "short-run"):
            r = c.post("/api/discrepancy", json={"run_id": target})
            assert r.status_code == 409 and "find missing effects after it ends" in r.json()["detail"]
        assert _finished(c, run_id)["status"] == "completed"

        assert anon.post("/api/discrepancy", json={"run_id": run_id}).status_code == 401
        r = c.post("/api/discrepancy", json={"run_id": "no-such-run"})
        assert r.status_code == 404 and r.json()["detail"] == "no test with id 'no-such-run'"
        r = c.post("/api/discrepancy", json={"run_id": "short-run"})
        assert r.status_code == 422 and r.json()["detail"] == "run 'short-run' has 5 samples: too few to compare"
        r = c.post("/api/discrepancy", json={"run_id": run_id, "effects": ["gremlins"]})
        assert r.status_code == 422 and r.json()["detail"].startswith("unknown effect 'gremlins' (known: time_skew")
        r = c.post("/api/discrepancy", json={"run_id": run_id, "signal_period_arcsec": -72})
        assert r.status_code == 422 and r.json()["detail"].startswith("signal_period_arcsec:")

        r = c.post("/api/discrepancy", json={"run_id": run_id, "signal_period_arcsec": 72})
        assert r.status_code == 201, r.text
        doc = r.json()
        assert r.headers["location"] == f"/api/discrepancy/{doc['id']}" and doc["run_id"] == run_id
        assert doc["options"] == {"signal_period_arcsec": 72.0, "effects": None}
        # no hidden effect on the default bench: nothing is named, the residual is the encoder noise (0.2″, less
        # after the workflow's resampling); the lower bound only rules out a run compared with itself
        assert doc["effects"] == [] and doc["aliases"] == [], doc
        assert 0.05 < doc["rms_before_arcsec"] < 0.3 and doc["cv_rms_after_arcsec"] < 0.3
        assert doc["verdict"] == "consistent" and doc["unexplained"] is None, doc["verdict_words"]
        assert doc["verdict_words"].startswith("Measurement and simulation agree")
        assert c.get(f"/api/discrepancy/{doc['id']}").json() == doc
        assert [a["id"] for a in c.get("/api/discrepancy").json()] == [doc["id"]]
        report = c.get(doc["report_url"])
        assert report.status_code == 200 and report.headers["content-type"].startswith("text/html")
        assert report.text.count("data:image/png;base64,") >= 2 and run_id in report.text
        assert "Verdict: consistent" in report.text
        model = c.get(f"/api/discrepancy/{doc['id']}/model")
        assert model.status_code == 200 and 'format = "tcms-discrepancy-model/1"' in model.text
        assert c.get("/api/discrepancy/20000101-000000-abcdef/report").status_code == 404
        assert c.get("/api/discrepancy/..%2F..%2Fetc/report").status_code == 404

        # restricting the candidates: only the listed effects can be named
        only = c.post("/api/discrepancy", json={"run_id": run_id, "effects": ["thermal_drift"]}).json()
        assert {e["name"] for e in only["effects"]} <= {"thermal_drift"}

        # the service reads the store while running; `tcms discrepancy --run` beside it gives the same object
        assert main(["discrepancy", "--run", run_id, "--data-dir", str(settings.data_dir), "--json"]) == 0
        cli_doc = json.loads(capsys.readouterr().out)
        assert set(cli_doc) - set(doc) == {"applied_version"} and cli_doc["applied_version"] is None
        assert cli_doc["id"] != doc["id"]
        assert ({k: v for k, v in doc.items() if k not in PER_ANALYSIS_KEYS}
                == {k: v for k, v in cli_doc.items() if k not in PER_ANALYSIS_KEYS | {"applied_version"}})


def bench_with_hidden_effects(sim_config, tmp_path, effects: dict) -> Path:
    """A copy of the default simulated bench config (paths made absolute) with ``[sim.effects]`` switched on."""
    data = tomllib.loads(sim_config.read_text(encoding="utf-8"))
    for key in ("compensation", "reducers"):
        data["bench"][key] = str(sim_config.parent / data["bench"][key])
    data["sim"]["geometry"] = str(sim_config.parent / data["sim"]["geometry"])
    data["sim"]["effects"] = effects
    config = tmp_path / f"bench-{'-'.join(effects)}.toml"
    config.write_text(tomli_w.dumps(data), encoding="utf-8")
    return config


@pytest.mark.timeout(120)
def test_discrepancy_names_an_effect_hidden_in_the_simulated_bench(settings_factory, sim_config, tmp_path):
    """[sim.effects] thermal_drift hidden in the bench: run 1 is analysed and the drift named; applied, it is
    the bench model's version 1; run 2 (new data) compared against version 1 is consistent (the gap is closed
    on data that did not choose the effect)."""
    config = bench_with_hidden_effects(sim_config, tmp_path, {"thermal_drift": {"rate_arcsec_per_s": 0.05}})
    with serve(settings_factory(config_path=config, sim_speed=20.0)) as srv, srv.client() as c, \
            srv.client(None) as anon:
        assert c.get("/api/model").json() == {"version": 0, "terms": [], "toml": None, "history": []}
        run_1 = c.post("/api/tests", json=REQUEST).json()["id"]
        assert _finished(c, run_1)["status"] == "completed"
        first = c.post("/api/discrepancy", json={"run_id": run_1}).json()
        assert first["model_version"] == 0
        # only the drift (before the re-simulation's torque lost its play-operator lag, 1 in ~8 runs under CPU
        # contention kept a small backlash/lag group beside it or named a lag in run 2)
        assert [e["name"] for e in first["effects"]] == ["thermal_drift"], (first["effects"], first["aliases"])
        # the 10 % recovery is pinned on simulated-clock runs in tests/discrepancy; this run is paced by the
        # wall clock at 20x and, on a loaded CI machine, its batches (and so the fit) vary more
        drift = next(e for e in first["effects"] if e["name"] == "thermal_drift")
        assert drift["parameters"]["rate_arcsec_per_s"] == pytest.approx(0.05, rel=0.25)
        assert first["cv_rms_after_arcsec"] < 0.3 < first["cv_rms_before_arcsec"]
        assert first["verdict"] == "explained" and not drift["provisional"], first["verdict_words"]

        assert anon.post(f"/api/discrepancy/{first['id']}/apply").status_code == 401
        assert c.post("/api/discrepancy/20000101-000000-abcdef/apply").status_code == 404
        r = c.post(f"/api/discrepancy/{first['id']}/apply")
        assert r.status_code == 200, r.text
        model = r.json()
        # the model gets what the analysis offered: its names, and the representative of any look-alike group it
        # kept in the model
        offered = [e["name"] for e in first["effects"]] + [a["representative"] for a in first["aliases"] if a["in_model"]]
        assert model["version"] == 1 and sorted(t["name"] for t in model["terms"]) == sorted(offered), first["aliases"]
        assert model["history"][0]["analysis_id"] == first["id"] and model["history"][0]["run_id"] == run_1
        assert c.get("/api/model").json() == model
        r = c.post(f"/api/discrepancy/{first['id']}/apply")  # made against version 0: applying twice is refused
        assert r.status_code == 409 and "analyse the run again" in r.json()["detail"]

        run_2 = c.post("/api/tests", json={**REQUEST, "max_torque_nm": 300}).json()["id"]
        assert _finished(c, run_2)["status"] == "completed"
        second = c.post("/api/discrepancy", json={"run_id": run_2}).json()
        assert second["model_version"] == 1
        assert second["verdict"] == "consistent" and second["effects"] == [], (second["verdict_words"],
                                                                                second["effects"])
        assert second["cv_rms_before_arcsec"] < 0.3
        r = c.post(f"/api/discrepancy/{second['id']}/apply")
        assert r.status_code == 422 and "nothing to add" in r.json()["detail"]
        listed = c.get("/api/discrepancy").json()
        assert [(a["id"], a["model_version"], a["verdict"]) for a in listed] == [
            (second["id"], 1, "consistent"), (first["id"], 0, "explained")]


@pytest.mark.timeout(180)
def test_a_measuring_chain_effect_moves_from_the_bench_model_into_the_compensator(settings_factory, sim_config,
                                                                                tmp_path):
    """A torsion of the measuring chain (0.004″/N·m) hidden in the bench: named, applied to the bench model, then moved to the
    compensator as its own version (POST /api/compensation/from-model); the bench model drops it and the next
    run, now compensated, is consistent with the model."""
    config = bench_with_hidden_effects(sim_config, tmp_path, {"torsion_offset": {"coef_arcsec_per_nm": 0.004}})
    with serve(settings_factory(config_path=config, sim_speed=20.0)) as srv, srv.client() as c:
        r = c.post("/api/compensation/from-model")
        assert r.status_code == 422 and "no measuring-chain effect" in r.json()["detail"]
        run_1 = c.post("/api/tests", json=REQUEST).json()["id"]
        assert _finished(c, run_1)["status"] == "completed"
        first = c.post("/api/discrepancy", json={"run_id": run_1}).json()
        assert [e["name"] for e in first["effects"]] == ["torsion_offset"], (first["verdict_words"], first["aliases"])
        assert first["effects"][0]["parameters"]["coef_arcsec_per_nm"] == pytest.approx(0.004, rel=0.15)
        assert c.post(f"/api/discrepancy/{first['id']}/apply").status_code == 200
        r = c.post("/api/compensation/from-model")
        assert r.status_code == 200, r.text
        assert 'type = "torsion"' in r.text
        version = int(r.headers["X-Compensation-Version"])
        history = c.get("/api/compensation/history").json()
        assert history[0]["version"] == version and "from bench model version 1" in history[0]["note"]
        model = c.get("/api/model").json()
        assert model["version"] == 2 and model["terms"] == [] and "moved torsion_offset" in model["history"][0]["note"]
        run_2 = c.post("/api/tests", json=REQUEST).json()["id"]
        assert _finished(c, run_2)["status"] == "completed"
        assert c.get(f"/api/tests/{run_2}").json()["compensation_version"] == version
        second = c.post("/api/discrepancy", json={"run_id": run_2}).json()
        assert second["model_version"] == 2
        assert second["verdict"] == "consistent" and second["effects"] == [], (second["verdict_words"],
                                                                                second["effects"])

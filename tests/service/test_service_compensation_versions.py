"""Compensation uploads are versioned (issue 10): each accepted upload is kept with time, note and hash, the
history is listed, an earlier version can be used again, every run records the version it used, and a restart
comes back with the version in use."""

from __future__ import annotations

import hashlib

import httpx
from svc_helpers import TOKEN, ScriptedRunner, serve, wait_for

from tcms_daq.service.app import FROM_CONFIG

SCALE = '[[terms]]\ntype = "scale"\ncoefficient = {}\n'
REQUEST = {"reducer": "RV-110E", "max_torque_nm": 300, "cycles": 1, "rate_nm_per_s": 300}


def _settings(data_dir):
    from tcms_daq.config.loader import default_bench_config_path
    from tcms_daq.service.app import ServiceSettings

    return ServiceSettings(data_dir=data_dir, api_token=TOKEN, config_path=default_bench_config_path(),
                           sim_speed=1000.0)


def test_uploads_are_versioned_rolled_back_and_recorded_by_each_run(tmp_path):
    with serve(_settings(tmp_path / "data")) as srv, srv.client() as c:
        # the bench configuration's compensation is version 1 (so that every run records a version)
        initial = c.get("/api/compensation/history").json()
        assert [h["version"] for h in initial] == [1]
        assert initial[0]["note"] == f"{FROM_CONFIG}: geometry-sim.toml"
        assert initial[0]["sha256"] == hashlib.sha256(c.get("/api/compensation").text.encode()).hexdigest()
        first = c.put("/api/compensation", params={"note": "cal 2026-11"}, content=SCALE.format(0.02).encode())
        assert first.status_code == 200 and first.headers["X-Compensation-Version"] == "2"
        second = c.put("/api/compensation", params={"note": "cal 2026-12"}, content=SCALE.format(-0.01).encode())
        assert second.headers["X-Compensation-Version"] == "3"
        history = c.get("/api/compensation/history").json()
        assert [h["version"] for h in history] == [3, 2, 1] and history[1]["note"] == "cal 2026-11"
        assert history[0]["sha256"] == hashlib.sha256(second.text.encode()).hexdigest()
        assert c.put("/api/compensation", content=SCALE.format(0.5).encode()).status_code == 422  # not kept
        assert len(c.get("/api/compensation/history").json()) == 3

        back = c.post("/api/compensation/rollback/2")
        assert back.status_code == 200 and back.text == first.text and back.headers["X-Compensation-Version"] == "4"
        assert c.get("/api/compensation/history").json()[0]["rollback_of"] == 2
        assert c.post("/api/compensation/rollback/99").status_code == 404
        assert httpx.post(srv.base + "/api/compensation/rollback/1").status_code == 401  # no token

        run_id = c.post("/api/tests", json=REQUEST).json()["id"]
        done = wait_for(lambda: (r := c.get(f"/api/tests/{run_id}").json())["status"] in
                        ("completed", "failed", "aborted") and r, timeout_s=120)
        assert done["compensation_version"] == 4
        assert done["compensation_sha256"] == hashlib.sha256(first.text.encode()).hexdigest()

    with serve(_settings(tmp_path / "data")) as srv, srv.client() as c:  # a restart uses the version in use
        assert c.get("/api/compensation").text == first.text
        assert len(c.get("/api/compensation/history").json()) == 4


def test_the_configured_compensation_is_a_version_and_a_changed_one_a_new_version(settings_factory):
    """A bench compensated from its configuration file records it as a version on the first start, keeps it over a
    restart, records the file again when it changed, and lets an upload win over the file after that."""

    def history(c) -> list[tuple[int, str]]:
        return [(h["version"], h["note"]) for h in c.get("/api/compensation/history").json()]

    runner = ScriptedRunner(bench_id="line-9")
    with serve(settings_factory(), runner=runner) as srv, srv.client() as c:
        assert history(c) == [(1, f"{FROM_CONFIG}: identity (no compensation)")]
        run_id = c.post("/api/tests", json={**REQUEST, "max_torque_nm": 200}).json()["id"]
        done = wait_for(lambda: (r := c.get(f"/api/tests/{run_id}").json())["status"] == "completed" and r,
                        timeout_s=60)
        assert done["compensation_version"] == 1
        assert done["compensation_sha256"] == hashlib.sha256(runner.compensation.encode()).hexdigest()
    with serve(settings_factory(), runner=ScriptedRunner(bench_id="line-9")) as srv, srv.client() as c:
        assert len(history(c)) == 1  # the same file: no new version
    changed = ScriptedRunner(bench_id="line-9")
    changed.compensation = "[compensator]\nterms = []\n# recalibrated\n"
    with serve(settings_factory(), runner=changed) as srv, srv.client() as c:
        assert [v for v, _ in history(c)] == [2, 1] and history(c)[0][1].startswith(FROM_CONFIG)
        assert c.put("/api/compensation", content=b"terms = []\n[compensator]\n# upload\n").status_code == 200
    again = ScriptedRunner(bench_id="line-9")
    with serve(settings_factory(), runner=again) as srv, srv.client() as c:
        assert [v for v, _ in history(c)] == [3, 2, 1]  # the upload stays in use over the configuration's file
        assert again.compensation.endswith("# upload\n")

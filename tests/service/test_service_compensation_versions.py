"""Compensation uploads are versioned (issue 10): each accepted upload is kept with time, note and hash, the
history is listed, an earlier version can be used again, every run records the version it used, and a restart
comes back with the version in use."""

from __future__ import annotations

import hashlib

import httpx
from svc_helpers import TOKEN, serve, wait_for

SCALE = '[[terms]]\ntype = "scale"\ncoefficient = {}\n'
REQUEST = {"reducer": "RV-110E", "max_torque_nm": 300, "cycles": 1, "rate_nm_per_s": 300}


def _settings(data_dir):
    from tcms_daq.config.loader import default_bench_config_path
    from tcms_daq.service.app import ServiceSettings

    return ServiceSettings(data_dir=data_dir, api_token=TOKEN, config_path=default_bench_config_path(),
                           sim_speed=1000.0)


def test_uploads_are_versioned_rolled_back_and_recorded_by_each_run(tmp_path):
    with serve(_settings(tmp_path / "data")) as srv, srv.client() as c:
        assert c.get("/api/compensation/history").json() == []
        first = c.put("/api/compensation", params={"note": "cal 2026-11"}, content=SCALE.format(0.02).encode())
        assert first.status_code == 200 and first.headers["X-Compensation-Version"] == "1"
        second = c.put("/api/compensation", params={"note": "cal 2026-12"}, content=SCALE.format(-0.01).encode())
        assert second.headers["X-Compensation-Version"] == "2"
        history = c.get("/api/compensation/history").json()
        assert [h["version"] for h in history] == [2, 1] and history[1]["note"] == "cal 2026-11"
        assert history[0]["sha256"] == hashlib.sha256(second.text.encode()).hexdigest()
        assert c.put("/api/compensation", content=SCALE.format(0.5).encode()).status_code == 422  # not kept
        assert len(c.get("/api/compensation/history").json()) == 2

        back = c.post("/api/compensation/rollback/1")
        assert back.status_code == 200 and back.text == first.text and back.headers["X-Compensation-Version"] == "3"
        assert c.get("/api/compensation/history").json()[0]["rollback_of"] == 1
        assert c.post("/api/compensation/rollback/99").status_code == 404
        assert httpx.post(srv.base + "/api/compensation/rollback/1").status_code == 401  # no token

        run_id = c.post("/api/tests", json=REQUEST).json()["id"]
        done = wait_for(lambda: (r := c.get(f"/api/tests/{run_id}").json())["status"] in
                        ("completed", "failed", "aborted") and r, timeout_s=120)
        assert done["compensation_version"] == 3
        assert done["compensation_sha256"] == hashlib.sha256(first.text.encode()).hexdigest()

    with serve(_settings(tmp_path / "data")) as srv, srv.client() as c:  # a restart uses the version in use
        assert c.get("/api/compensation").text == first.text

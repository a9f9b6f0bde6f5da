"""The docker-compose topology without Docker: ``tcms sim serve`` (the instrument simulators speaking ND 287,
AED and CANopen/socketcand) and ``tcms serve`` as two processes on loopback, with config/bench-compose.toml's
instruments pointed at the simulator process instead of the host ``sim``."""

from __future__ import annotations

import tomllib
from pathlib import Path

import httpx
import pytest
import tomli_w
from svc_helpers import TOKEN, start_serve_process, stop_process, wait_for
from tcms_daq.sim.instruments.child import start_simulators

REPO = Path(__file__).resolve().parents[2]


@pytest.mark.timeout(180)
def test_service_and_simulators_as_two_processes(tmp_path):
    compose_cfg = REPO / "config" / "bench-compose.toml"
    sim, info = start_simulators("--config", str(compose_cfg), cwd=REPO)
    service = None
    try:
        urls = info["urls"]
        data = tomllib.loads(compose_cfg.read_text(encoding="utf-8"))
        data["instruments"]["angle"]["url"] = urls["angle"]
        data["instruments"]["torque"]["url"] = urls["torque"]
        data["instruments"]["loader"]["url"] = urls["loader_canopen"]
        for key in ("reducers", "compensation"):
            data["bench"][key] = str(REPO / "config" / data["bench"][key])
        cfg = tmp_path / "bench-loopback-compose.toml"
        cfg.write_text(tomli_w.dumps(data), encoding="utf-8")

        service, base = start_serve_process(
            ["--config", str(cfg), "--port", "0", "--data-dir", str(tmp_path / "data")], cwd=REPO
        )
        c = httpx.Client(base_url=base, headers={"Authorization": f"Bearer {TOKEN}"}, timeout=20)
        wait_for(lambda: c.get("/api/health").status_code == 200, timeout_s=30)
        bench = c.get("/api/bench").json()
        assert bench["clock"] == "monotonic"
        assert bench["instruments"]["angle"]["driver"] == "nd287"
        assert bench["instruments"]["loader"]["driver"] == "cia402-canopen"

        r = c.post("/api/tests", json={"reducer": "RV-110E", "max_torque_nm": 300, "cycles": 1,
                                       "profile": "continuous", "rate_nm_per_s": 600})
        assert r.status_code == 202, r.text
        run_id = r.json()["id"]
        run = wait_for(lambda: (t := c.get(f"/api/tests/{run_id}").json())["status"]
                       in ("completed", "failed", "aborted") and t, timeout_s=90)
        assert run["status"] == "completed", run["error"]
        assert 200 < run["results"]["rigidity_nm_per_arcmin"] < 400
        assert run["sample_count"] > 100
    finally:
        if service is not None:
            stop_process(service)
        stop_process(sim)

"""End to end over HTTP and WebSocket with the real bench runner (acquisition loop, procedure state machine,
compensation, analysis) on the in-process simulated bench, the simulated clock running faster than real time."""

from __future__ import annotations

import io
import json

import numpy as np
import pyarrow.parquet as pq
import pytest
import websocket
from svc_helpers import TOKEN, kill_during_a_run, serve, start_serve_process, stop_process, wait_for
from test_service_api import LiveReader

from tcms_daq.samples import parse_csv_text

REQUEST = {"reducer": "RV-110E", "max_torque_nm": 500, "cycles": 1, "profile": "continuous", "rate_nm_per_s": 250}


def test_http_and_websocket_end_to_end(settings_factory, sim_config, tmp_path):
    settings = settings_factory(config_path=sim_config, sim_speed=20.0)
    with serve(settings) as srv, srv.client() as c, srv.client(None) as anon:
        bench = c.get("/api/bench").json()
        assert bench["clock"] == "simulated" and {r["name"] for r in bench["reducers"]} >= {"RV-110E", "RV-60N"}
        assert anon.post("/api/tests", json=REQUEST).status_code == 401
        r = c.post("/api/tests", json={**REQUEST, "reducer": "RV-1"})
        assert r.status_code == 422 and r.json()["detail"].startswith("unknown reducer 'RV-1' (known: RV-110E")
        r = c.post("/api/tests", json={**REQUEST, "max_torque_nm": 1500})
        assert r.status_code == 422 and "rated torque 1078 N·m of RV-110E" in r.json()["detail"]
        r = c.post("/api/tests", json={**REQUEST, "max_torque_nm": 2500, "reducer": "RV-110E"})
        assert r.status_code == 422 and "bench limit 2000 N·m" in r.json()["detail"]
        r = c.post("/api/tests", json={**REQUEST, "rate_nm_per_s": -5})
        assert r.status_code == 422 and r.json()["detail"].startswith("rate_nm_per_s:")
        assert c.get("/api/tests/does-not-exist").status_code == 404

        live = LiveReader(f"{srv.ws_base}/ws/live")
        live.start()
        events = websocket.create_connection(f"{srv.ws_base}/ws/events", timeout=10)
        r = c.post("/api/tests", json=REQUEST)
        assert r.status_code == 202 and r.json()["status"] == "queued"
        run_id = r.json()["id"]
        assert c.post("/api/tests", json=REQUEST).status_code == 409
        run = wait_for(lambda: (t := c.get(f"/api/tests/{run_id}").json())["status"] in
                       ("completed", "failed", "aborted") and t, timeout_s=60)
        live.close()
        assert run["status"] == "completed", run["error"]
        res = run["results"]
        assert 200 < res["rigidity_nm_per_arcmin"] < 400 and res["verdict"]["passed"] in (True, False)
        assert {"lost_motion_arcsec", "backlash_arcsec", "loops", "per_direction"} <= set(res)

        seqs = [f.sequence for f in live.frames]
        assert len(seqs) > 10 and seqs == list(range(seqs[0], seqs[0] + len(seqs)))
        assert all(f.dropped == 0 for f in live.frames)
        peak = max(np.abs(f.columns["torque_nm"]).max() for f in live.frames)
        assert 450 < peak < 560  # the test's torque went through the live stream

        phases = []
        while "completed" not in phases:
            e = json.loads(events.recv())
            if e.get("id") == run_id:
                phases.append(e.get("status") or e.get("phase"))
        events.close()
        assert phases[0] == "queued" and "loading" in phases and "evaluating" in phases

        n = run["sample_count"]
        csv = parse_csv_text(c.get(f"/api/tests/{run_id}/samples?format=csv").text)
        assert len(csv["time_s"]) == n > 1000 and np.all(np.diff(csv["time_s"]) > 0)
        assert 450 < np.abs(csv["torque_nm"]).max() < 560
        js = c.get(f"/api/tests/{run_id}/samples?format=json").json()
        np.testing.assert_array_equal(js["data"]["angle_arcsec"], csv["angle_arcsec"])
        pq_table = pq.read_table(io.BytesIO(c.get(f"/api/tests/{run_id}/samples?format=parquet").content))
        np.testing.assert_array_equal(pq_table.column("encoder_arcsec").to_numpy(), csv["encoder_arcsec"])
        (tmp_path / "r.mf4").write_bytes(c.get(f"/api/tests/{run_id}/samples?format=mdf4").content)
        from asammdf import MDF

        with MDF(tmp_path / "r.mf4") as mdf:
            np.testing.assert_array_equal(mdf.get("angle_arcsec").samples, csv["angle_arcsec"])
        report = c.get(f"/api/tests/{run_id}/report").text
        assert "<svg" in report and "rigidity_nm_per_arcmin" in report

        # abort a running test: the procedure ramps down, the run ends 'aborted' with its samples
        slow = c.post("/api/tests", json={**REQUEST, "rate_nm_per_s": 20}).json()["id"]
        wait_for(lambda: c.get(f"/api/tests/{slow}").json()["sample_count"] > 200, timeout_s=30)
        assert c.post(f"/api/tests/{slow}/abort").status_code == 202
        aborted = wait_for(lambda: (t := c.get(f"/api/tests/{slow}").json())["status"] != "running"
                           and t["status"] != "queued" and t, timeout_s=30)
        assert aborted["status"] == "aborted" and aborted["error"] == "aborted by the operator"
        assert aborted["sample_count"] > 200
        loader = c.get("/api/bench").json()["instruments"]["loader"]["status"]
        assert loader["state"] != "OPERATION ENABLED" and abs(loader["torque_actual_nm"]) < 25

        comp = c.get("/api/compensation")
        assert comp.status_code == 200 and "[compensator]" in comp.text
        assert c.put("/api/compensation", content="[compensator\n").status_code == 422
        assert c.put("/api/compensation", content=comp.text).status_code == 200


def _start_service(data_dir, config):
    return start_serve_process(["--port", "0", "--data-dir", str(data_dir), "--config", str(config),
                                "--sim-speed", "5"])


def test_serve_banner_shows_dashboard_url_with_token_and_the_bench(sim_config, tmp_path):
    """What `tcms serve` prints for a test engineer; the printed URL answers at once (the socket listens)."""
    import httpx

    proc, base = _start_service(tmp_path / "fresh", sim_config)
    try:
        banner = [proc.stdout.readline().strip() for _ in range(6)]
        assert httpx.get(f"{base}/api/health", timeout=20).json() == {"status": "ok"}
    finally:
        stop_process(proc)
    rest = proc.stdout.read()
    assert banner[0] == f"Dashboard:  {base}/?token={TOKEN}    <- open this in a browser"
    assert banner[1].startswith(f"API token:  {TOKEN}  (from TCMS_API_TOKEN;")
    assert banner[2] == f"API docs:   {base}/docs"
    assert banner[3] == f"Bench:      simulated bench ({sim_config}), simulated clock at 5× real time"
    assert banner[4] == f"Run store:  {(tmp_path / 'fresh' / 'tcms-runs.sqlite3').resolve()} (bench id sim-1)"
    assert banner[5].startswith("Stop with Ctrl+C") and rest.startswith("TCMS-DAQ service stopping: ")


@pytest.mark.timeout(120)
def test_killed_service_marks_run_interrupted_and_keeps_samples(sim_config, tmp_path):
    import httpx

    data_dir = tmp_path / "data"
    proc, base = _start_service(data_dir, sim_config)
    run_id = kill_during_a_run(proc, base, {**REQUEST, "rate_nm_per_s": 50, "cycles": 3})

    proc2, base2 = _start_service(data_dir, sim_config)
    try:
        c2 = httpx.Client(base_url=base2, timeout=20)
        run = wait_for(lambda: c2.get(f"/api/tests/{run_id}").json())
        assert run["status"] == "interrupted" and run["sample_count"] > 500
        assert "stopped" in run["error"]
        csv = parse_csv_text(c2.get(f"/api/tests/{run_id}/samples?format=csv").text)
        assert len(csv["time_s"]) == run["sample_count"]
        assert c2.get("/api/bench").json()["active_test"] is None
    finally:
        stop_process(proc2)

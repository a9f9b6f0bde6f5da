"""A multi-position test through the service: 422 for bad plans, progress events on /ws/events (loop, loops,
position, positions, elapsed_s, eta_s) with an ETA that runs down to zero, per-position results and report."""

from __future__ import annotations

import json

import pytest
import websocket
from svc_helpers import serve, wait_for

REQUEST = {"reducer": "RV-110E", "max_torque_nm": 300, "cycles": 1, "rate_nm_per_s": 300}


@pytest.mark.parametrize(("extra", "fragment"), [
    ({"positions": 0}, "positions must be 1…36"),
    ({"positions": 37}, "positions must be 1…36"),
    ({"positions": [0, 400]}, "[0, 360)"),
    ({"positions": [10, 10]}, "repeated"),
    ({"positions": 2.5}, "positions"),
    ({"positions": []}, "positions"),
    ({"rates": [50, 50]}, "repeated"),
    ({"rates": [50] * 11}, "rates"),
    ({"rates": [50, 500], "positions": 4}, "cannot be combined"),
    ({"rates": [50, 500]}, "exclude each other"),  # rate_nm_per_s of REQUEST as well
    ({"move_velocity_deg_per_s": 10}, "positions only"),
    ({"positions": 4, "move_velocity_deg_per_s": 0}, "move_velocity_deg_per_s"),
])
def test_bad_plans_are_422(settings_factory, sim_config, extra, fragment):
    with serve(settings_factory(config_path=sim_config, sim_speed=50.0)) as srv, srv.client() as c:
        r = c.post("/api/tests", json={**REQUEST, **extra})
        assert r.status_code == 422, r.text
        assert fragment in json.dumps(r.json(), ensure_ascii=False)
        r = c.post("/api/tests", json={**REQUEST, "rate_nm_per_s": None, "rates": [0.01, 50]})
        assert r.status_code == 422 and "slowest rate" in r.json()["detail"]


def test_multi_position_test_streams_progress(settings_factory, sim_config):
    with serve(settings_factory(config_path=sim_config, sim_speed=50.0)) as srv, srv.client() as c:
        events = websocket.create_connection(f"{srv.ws_base}/ws/events", timeout=10)
        r = c.post("/api/tests", json={**REQUEST, "positions": 4})
        assert r.status_code == 202, r.text
        run_id = r.json()["id"]
        run = wait_for(lambda: (t := c.get(f"/api/tests/{run_id}").json())["status"] in
                       ("completed", "failed", "aborted") and t, timeout_s=120)
        assert run["status"] == "completed", run["error"]
        progress = []
        while True:
            e = json.loads(events.recv())
            if e.get("type") == "test_progress" and e["id"] == run_id:
                progress.append(e)
            if e.get("type") == "test_state" and e.get("status") == "completed":
                break
        events.close()
        assert {"loop", "loops", "position", "positions", "elapsed_s", "eta_s"} <= set(progress[0])
        assert {e["position"] for e in progress} == {1, 2, 3, 4} and {e["positions"] for e in progress} == {4}
        assert any(e["moving"] for e in progress) and {e["loop"] for e in progress} >= {0, 1}
        assert all(e["loops"] == 1 for e in progress)
        assert progress[0]["eta_s"] > 0 and progress[-1]["eta_s"] == 0.0
        elapsed = [e["elapsed_s"] for e in progress]
        assert elapsed == sorted(elapsed) and progress[-1]["elapsed_s"] > 0
        res = run["results"]
        assert [e["position_deg"] for e in res["positions"]] == [0.0, 90.0, 180.0, 270.0]
        for e in res["positions"]:  # the simple model: the same reducer at every position
            assert 280 < e["rigidity_nm_per_arcmin"] < 330
        assert res["lost_motion_arcsec_max"] == max(e["lost_motion_arcsec"] for e in res["positions"])
        identity = c.get(f"/api/tests/{run_id}/metadata").json()["identity"]  # the exports' identity
        assert identity["parameters"]["positions_deg"] == [0.0, 90.0, 180.0, 270.0]
        assert identity["method"] == {"kind": "positions", "stages": 4, "series": "positions-4"}
        assert identity["compensation_version"] == 1 and identity["bench_model_version"] == 0
        report = c.get(f"/api/tests/{run_id}/report")
        assert report.status_code == 200 and "Positions (GB/T 40731)" in report.text
        stages = report.text.split("Positions (GB/T 40731)")[1].split("</table>")[0]
        assert stages.count(" ± ") == 3 * 4, stages  # each position's three results with their U

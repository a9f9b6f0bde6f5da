"""REST, auth, WebSocket and store behaviour of the service over real HTTP, with the scripted test runner."""

from __future__ import annotations

import io
import json
import threading

import numpy as np
import pyarrow.parquet as pq
import websocket
from svc_helpers import TOKEN, ScriptedRunner, serve, wait_for

from tcms_daq.samples import parse_csv_text
from tcms_daq.service.live import decode_frame

REQUEST = {"reducer": "RV-110E", "max_torque_nm": 500, "cycles": 2, "profile": "continuous", "rate_nm_per_s": 2000}


class LiveReader(threading.Thread):
    def __init__(self, url: str):
        super().__init__(daemon=True)
        self.ws = websocket.create_connection(url, timeout=10)
        self.schema = json.loads(self.ws.recv())
        self.frames = []
        self.stop = threading.Event()

    def run(self) -> None:
        while not self.stop.is_set():
            try:
                data = self.ws.recv()
            except Exception:
                return
            if not isinstance(data, bytes):  # '' when the socket closes
                return
            self.frames.append(decode_frame(data))

    def close(self) -> None:
        self.stop.set()
        self.ws.close()
        self.join(5)


def test_rest_auth_errors_run_to_completion_and_exports(settings_factory, tmp_path):
    with serve(settings_factory(), runner=ScriptedRunner()) as srv, srv.client() as c, srv.client(None) as anon:
        assert c.get("/api/health").json() == {"status": "ok"}
        assert c.get("/api/bench").json()["name"] == "scripted bench"
        assert "/api/tests" in c.get("/openapi.json").json()["paths"]

        # auth
        assert anon.post("/api/tests", json=REQUEST).status_code == 401
        r = anon.post("/api/tests", json=REQUEST, headers={"Authorization": "Bearer wrong"})
        assert r.status_code == 401 and "bearer token" in r.json()["detail"]
        # validation, with a clear one-line message
        r = c.post("/api/tests", json={**REQUEST, "cycles": 0})
        assert r.status_code == 422 and r.json()["detail"].startswith("cycles:")
        r = c.post("/api/tests", json={**REQUEST, "color": "red"})
        assert r.status_code == 422 and "color" in r.json()["detail"]
        r = c.post("/api/tests", json={**REQUEST, "reducer": "RV-9999"})
        assert r.status_code == 422 and r.json()["detail"] == "unknown reducer 'RV-9999' (known: RV-110E)"
        r = c.post("/api/tests", json={**REQUEST, "max_torque_nm": 1500})
        assert r.status_code == 422 and "exceeds the bench limit" in r.json()["detail"]
        r = c.post("/api/tests", json={**REQUEST, "step_nm": 50})
        assert r.status_code == 422 and "only to profile 'stepped'" in r.json()["detail"]
        # 404s
        assert c.get("/api/tests/nope").status_code == 404
        assert c.post("/api/tests/nope/abort").status_code == 404
        assert c.get("/api/tests/nope/samples?format=csv").status_code == 404
        assert c.get("/api/tests/nope/report").status_code == 404

        events = websocket.create_connection(f"{srv.ws_base}/ws/events", timeout=10)
        assert json.loads(events.recv())["type"] == "hello"
        live = LiveReader(f"{srv.ws_base}/ws/live")
        live.start()
        assert [ch["name"] for ch in live.schema["channels"]] == ["time_s", "torque_nm", "encoder_arcsec", "angle_arcsec"]

        r = c.post("/api/tests", json=REQUEST)
        assert r.status_code == 202
        run_id = r.json()["id"]
        r2 = c.post("/api/tests", json=REQUEST)
        assert r2.status_code == 409 and run_id in r2.json()["detail"]

        done = wait_for(lambda: (t := c.get(f"/api/tests/{run_id}").json())["status"] == "completed" and t)
        assert done["results"]["passed"] is True and done["sample_count"] > 1000
        assert c.post(f"/api/tests/{run_id}/abort").status_code == 409  # no longer active
        live.close()

        seqs = [f.sequence for f in live.frames]
        assert len(seqs) > 5 and seqs == list(range(seqs[0], seqs[0] + len(seqs)))  # no gaps
        assert all(f.dropped == 0 for f in live.frames)

        states = []
        while len(states) < 3:
            e = json.loads(events.recv())
            if e["type"] == "test_state":
                states.append((e["seq"], e["status"]))
        events.close()
        assert [s for _, s in states] == ["queued", "running", "completed"]
        assert [q for q, _ in states] == sorted(q for q, _ in states)

        # samples in every format, read back
        csv = parse_csv_text(c.get(f"/api/tests/{run_id}/samples?format=csv").text)
        n = done["sample_count"]
        assert len(csv["time_s"]) == n and set(csv) >= {"time_s", "torque_nm", "angle_arcsec", "encoder_arcsec"}
        js = c.get(f"/api/tests/{run_id}/samples", params={"format": "json"}).json()
        assert js["columns"][:3] == ["time_s", "torque_nm", "angle_arcsec"]
        np.testing.assert_array_equal(js["data"]["torque_nm"], csv["torque_nm"])
        table = pq.read_table(io.BytesIO(c.get(f"/api/tests/{run_id}/samples?format=parquet").content))
        np.testing.assert_array_equal(table.column("angle_arcsec").to_numpy(), csv["angle_arcsec"])
        mdf_path = tmp_path / "run.mf4"
        mdf_path.write_bytes(c.get(f"/api/tests/{run_id}/samples?format=mdf4").content)
        from asammdf import MDF

        with MDF(mdf_path) as mdf:
            sig = mdf.get("torque_nm")
            np.testing.assert_array_equal(sig.samples, csv["torque_nm"])
            # MDF4 counts from the first sample; its header's start time is the test's start
            np.testing.assert_allclose(sig.timestamps, csv["time_s"] - csv["time_s"][0], rtol=0, atol=1e-9)
        assert c.get(f"/api/tests/{run_id}/samples?format=xlsx").status_code == 422

        report = c.get(f"/api/tests/{run_id}/report")
        assert report.status_code == 200 and "<svg" in report.text and "rigidity_nm_per_arcmin" in report.text

        listed = c.get("/api/tests").json()
        assert listed[0]["id"] == run_id and listed[0]["status"] == "completed"

        metrics = c.get("/metrics").text
        assert 'tcms_tests{status="completed"} 1.0' in metrics
        assert "tcms_acquisition_rate_samples_per_second" in metrics and "tcms_live_dropped_frames_total" in metrics


def test_abort_and_compensation(settings_factory):
    with serve(settings_factory(), runner=ScriptedRunner(speed=1.0)) as srv, srv.client() as c:
        run_id = c.post("/api/tests", json={**REQUEST, "rate_nm_per_s": 100}).json()["id"]
        wait_for(lambda: c.get(f"/api/tests/{run_id}").json()["status"] == "running")
        assert c.put("/api/compensation", content="[compensator]\n").status_code == 409
        assert srv.client(None).post(f"/api/tests/{run_id}/abort").status_code == 401
        assert c.post(f"/api/tests/{run_id}/abort").status_code == 202
        rec = wait_for(lambda: (t := c.get(f"/api/tests/{run_id}").json())["status"] == "aborted" and t)
        assert rec["error"] == "aborted by the operator" and rec["sample_count"] > 0

        assert c.get("/api/compensation").text.startswith("[compensator]")
        assert srv.client(None).put("/api/compensation", content="[compensator]\nx = 1\n").status_code == 401
        bad = c.put("/api/compensation", content="nonsense")
        assert bad.status_code == 422 and "invalid TOML" in bad.json()["detail"]
        ok = c.put("/api/compensation", content="[compensator]\n[[terms]]\ntype = 'offset'\nvalue_arcsec = 1.0\n")
        assert ok.status_code == 200 and "offset" in c.get("/api/compensation").text


def test_token_is_generated_when_none_is_configured(settings_factory, monkeypatch):
    monkeypatch.delenv("TCMS_API_TOKEN", raising=False)
    with serve(settings_factory(api_token=None), runner=ScriptedRunner()) as srv:
        token = srv.app.state.api_token
        assert srv.app.state.api_token_source == "generated" and len(token) >= 24 and token != TOKEN
        with srv.client(token) as c:
            assert c.post("/api/tests", json={**REQUEST, "reducer": "x"}).status_code == 422  # authorised
    monkeypatch.setenv("TCMS_API_TOKEN", "from-env")
    with serve(settings_factory(api_token=None), runner=ScriptedRunner()) as srv:
        assert srv.app.state.api_token == "from-env" and srv.app.state.api_token_source == "environment"


def test_dashboard_and_vendored_uplot_are_served(settings_factory):
    with serve(settings_factory(), runner=ScriptedRunner()) as srv, srv.client() as c:
        page = c.get("/")
        assert page.status_code == 200 and "/static/vendor/uplot/uPlot.iife.min.js" in page.text
        assert "http" not in page.text.split("<body>")[1].split("cdn")[0] or "cdn" not in page.text
        js = c.get("/static/vendor/uplot/uPlot.iife.min.js")
        assert js.status_code == 200 and "uPlot" in js.text
        assert "MIT" in c.get("/static/vendor/uplot/LICENSE").text
        assert c.get("/static/app.js").status_code == 200

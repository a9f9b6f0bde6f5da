"""Strict requests (issue 22): no coercion of types in request bodies, torques below the bench's minimum test torque
refused, invalid strings (lone surrogates) a 422 that can be sent, and tokens in no log line at any level."""

from __future__ import annotations

import json
import socket
import threading
import time

import httpx
import pytest
import uvicorn
import websocket
from svc_helpers import TOKEN, ScriptedRunner, serve

GOOD = {"reducer": "RV-110E", "max_torque_nm": 500, "cycles": 1, "rate_nm_per_s": 250}


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    from tcms_daq.config.loader import default_bench_config_path
    from tcms_daq.service.app import ServiceSettings

    settings = ServiceSettings(data_dir=tmp_path_factory.mktemp("data"), api_token=TOKEN,
                               config_path=default_bench_config_path(), sim_speed=1000.0)
    with serve(settings) as srv:
        yield srv


def _post(srv, body: bytes) -> httpx.Response:
    return httpx.post(srv.base + "/api/tests", content=body, timeout=20,
                      headers={"Content-Type": "application/json", "Authorization": f"Bearer {TOKEN}"})


@pytest.mark.parametrize(("change", "named"), [
    ({"cycles": True}, "cycles"),
    ({"cycles": 2.0}, "cycles"),
    ({"max_torque_nm": "500"}, "max_torque_nm"),
    ({"max_torque_nm": True}, "max_torque_nm"),
    ({"rate_nm_per_s": "250"}, "rate_nm_per_s"),
    ({"ambient_temperature_c": "20"}, "ambient_temperature_c"),
    ({"positions": [True, 90]}, "positions"),
    ({"serial_number": 12345}, "serial_number"),
])
def test_no_type_is_coerced_in_a_request_body(server, change, named):
    r = _post(server, json.dumps({**GOOD, **change}).encode())
    assert r.status_code == 422, r.text
    assert named in r.json()["detail"]


@pytest.mark.parametrize("torque", [0.001, 1e-300, 0.5])
def test_a_torque_below_the_bench_minimum_is_422(server, torque):
    r = _post(server, json.dumps({**GOOD, "max_torque_nm": torque}).encode())
    assert r.status_code == 422, r.text
    assert "minimum test torque" in r.json()["detail"] and "\n" not in r.json()["detail"]
    with server.client() as c:
        assert c.get("/api/bench").json()["test_bounds"]["min_torque_nm"] == 1.0


@pytest.mark.parametrize("body", [
    b'{"reducer": "RV-110E", "max_torque_nm": 500, "serial_number": "\\ud800"}',
    b'{"reducer": "RV-110E", "max_torque_nm": 500, "operator": "ab\\udfffcd"}',
    b'{"reducer": "\\ud83d", "max_torque_nm": 500}',
    b'{"reducer": "RV-110E", "max_torque_nm": 500, "\\ud800": 1}',
    b'{"reducer": "RV-110E", "max_torque_nm": 500, "positions": ["\\udc00"]}',
])
def test_a_lone_surrogate_anywhere_is_a_422_that_can_be_sent(server, body):
    r = _post(server, body)
    assert r.status_code == 422, r.text
    assert "lone surrogate" in r.json()["detail"] or "\\ud" in r.text
    with server.client() as c:  # nothing was stored, the service answers
        assert all(run.get("serial_number") is None or "\ud800" not in run["serial_number"]
                   for run in c.get("/api/tests").json())


def test_a_valid_request_with_unicode_text_is_accepted(server):
    r = _post(server, json.dumps({**GOOD, "operator": "Zoë 😀", "cycles": 1}).encode())
    assert r.status_code in (201, 202), r.text
    with server.client() as c:
        c.post(f"/api/tests/{r.json()['id']}/abort")


def test_tokens_are_in_no_log_line_at_debug_level(tmp_path, capfd):
    """uvicorn at debug level (its access lines and WebSocket lines print the path with its query) and the
    service's own loggers: the token given as ?token= appears nowhere, masked as token=***."""
    from tcms_daq.service.app import ServiceSettings, create_app

    app = create_app(ServiceSettings(data_dir=tmp_path / "data", api_token=TOKEN), runner=ScriptedRunner())
    sock = socket.socket()
    sock.bind(("127.0.0.1", 0))
    port = sock.getsockname()[1]
    server = uvicorn.Server(uvicorn.Config(app, log_level="debug", ws_per_message_deflate=False))
    thread = threading.Thread(target=server.run, kwargs={"sockets": [sock]}, daemon=True)
    thread.start()
    try:
        deadline = time.monotonic() + 60
        while not server.started:
            assert time.monotonic() < deadline and thread.is_alive(), "service did not start"
            time.sleep(0.02)
        assert httpx.get(f"http://127.0.0.1:{port}/api/bench?token={TOKEN}", timeout=20).status_code == 200
        ws = websocket.create_connection(f"ws://127.0.0.1:{port}/ws/events?token={TOKEN}", timeout=20)
        ws.close()
        httpx.get(f"http://127.0.0.1:{port}/no/such/page?a=1&token={TOKEN}", timeout=20)
    finally:
        server.should_exit = True
        thread.join(30)
    out, err = capfd.readouterr()
    logged = out + err
    assert "WebSocket" in logged and "GET /api/bench" in logged  # the lines that carried the token were logged
    assert TOKEN not in logged
    assert "token=***" in logged

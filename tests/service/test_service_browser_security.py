"""Browser-facing security (issue 10): a page on another site cannot open the WebSockets, a rebinding DNS name
cannot reach the API, and the dashboard token stays out of the access log."""

from __future__ import annotations

import logging

import httpx
import pytest
import websocket
from svc_helpers import TOKEN, ScriptedRunner, serve

from tcms_daq.service.auth import RedactTokenInAccessLog


@pytest.mark.parametrize("path", ["/ws/live", "/ws/events"])
def test_a_foreign_origin_is_refused_on_both_websockets(settings_factory, path):
    with serve(settings_factory(), runner=ScriptedRunner()) as srv:
        url = srv.ws_base + path
        with pytest.raises(websocket.WebSocketBadStatusException) as refused:
            websocket.create_connection(url, timeout=5, origin="http://evil.example")
        assert refused.value.status_code == 403
        own = websocket.create_connection(url, timeout=5, origin=srv.base)  # the dashboard's own page
        own.close()
        plain = websocket.create_connection(url, timeout=5, suppress_origin=True)  # a script, no Origin
        plain.close()


def test_an_unknown_host_header_is_refused(settings_factory):
    with serve(settings_factory(), runner=ScriptedRunner()) as srv:
        assert httpx.get(srv.base + "/api/health", timeout=5).status_code == 200
        rebound = httpx.get(srv.base + "/api/health", headers={"Host": "attacker.example"}, timeout=5)
        assert rebound.status_code == 400


def test_the_token_is_masked_in_access_log_lines():
    record = logging.LogRecord("uvicorn.access", logging.INFO, __file__, 1, '%s - "%s %s HTTP/%s" %d',
                               ("127.0.0.1:5", "GET", "/?token=s3cret&x=1", "1.1", 200), None)
    assert RedactTokenInAccessLog().filter(record)
    assert "s3cret" not in record.getMessage() and "token=***&x=1" in record.getMessage()


def test_reads_need_the_token_when_configured(settings_factory):
    """A service reachable from other machines (``--read-token``, on by default beyond loopback): every read
    needs the token, by header or ``?token=``; liveness, the dashboard's files and the API description stay
    open."""
    with serve(settings_factory(read_token_required=True), runner=ScriptedRunner()) as srv:
        anonymous = httpx.Client(base_url=srv.base, timeout=5)
        for path in ("/api/tests", "/api/bench", "/api/compensation", "/api/discrepancy", "/metrics",
                     "/api/tests/nope/samples"):
            r = anonymous.get(path)
            assert r.status_code == 401, path
            assert r.headers["www-authenticate"] == "Bearer"
        for path in ("/api/health", "/", "/openapi.json", "/docs"):
            assert anonymous.get(path).status_code == 200, path
        assert anonymous.get("/api/tests", params={"token": "wrong"}).status_code == 401
        assert anonymous.get("/api/tests", params={"token": TOKEN}).status_code == 200
        with srv.client() as client:
            assert client.get("/api/bench").status_code == 200
        for path in ("/ws/live", "/ws/events"):
            with pytest.raises(websocket.WebSocketBadStatusException):
                websocket.create_connection(srv.ws_base + path, timeout=5)
            websocket.create_connection(f"{srv.ws_base}{path}?token={TOKEN}", timeout=5).close()


def test_reads_stay_open_on_loopback_by_default(settings_factory):
    with serve(settings_factory(), runner=ScriptedRunner()) as srv:
        assert httpx.get(srv.base + "/api/tests", timeout=5).status_code == 200


@pytest.mark.parametrize("host, loopback", [("127.0.0.1", True), ("::1", True), ("localhost", True),
                                            ("0.0.0.0", False), ("::", False), ("192.168.10.7", False),
                                            ("bench-pc.lab", False)])
def test_read_token_auto_follows_the_bound_interface(host, loopback):
    from tcms_daq.cli.serve import _loopback

    assert _loopback(host) is loopback


def test_openapi_names_the_bearer_scheme_on_protected_operations(settings_factory):
    with serve(settings_factory(), runner=ScriptedRunner()) as srv:
        doc = httpx.get(srv.base + "/openapi.json", timeout=5).json()
    scheme = doc["components"]["securitySchemes"]["HTTPBearer"]
    assert scheme["type"] == "http" and scheme["scheme"] == "bearer"
    assert "the service token (printed by `tcms serve`)" in scheme["description"]
    assert "API token" in scheme["description"]
    assert doc["paths"]["/api/tests"]["post"]["security"] == [{"HTTPBearer": []}]
    assert "security" not in doc["paths"]["/api/tests"]["get"]


def test_every_operation_has_a_readable_id_a_typed_answer_and_documented_errors(settings_factory):
    """The API contract (issue 13 item 4): operation ids are the handlers' names; every JSON answer has a
    schema; mutating operations name the bearer scheme and document 401; routes with a path id document 404."""
    import re

    with serve(settings_factory(), runner=ScriptedRunner()) as srv:
        doc = httpx.get(srv.base + "/openapi.json", timeout=5).json()
    seen = set()
    for path, operations in doc["paths"].items():
        for method, op in operations.items():
            assert re.fullmatch(r"[a-z][a-z_]*", op["operationId"]), op["operationId"]
            assert op["operationId"] not in seen
            seen.add(op["operationId"])
            ok = next(v for k, v in op["responses"].items() if k.startswith("2"))
            json_answer = ok.get("content", {}).get("application/json")
            if json_answer is not None:
                assert json_answer["schema"] not in ({}, {"type": "object"}) or path.endswith("/profile"), path
            if method in ("post", "put", "delete") and path != "/api/login":  # signing in needs no credential
                assert op.get("security") == [{"HTTPBearer": []}], (method, path)
                assert "401" in op["responses"]
            if "{" in path:
                assert "404" in op["responses"], path
    assert len(seen) >= 20

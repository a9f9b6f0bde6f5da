"""Browser-facing security (issue 10): a page on another site cannot open the WebSockets, a rebinding DNS name
cannot reach the API, and the dashboard token stays out of the access log."""

from __future__ import annotations

import logging

import httpx
import pytest
import websocket
from svc_helpers import ScriptedRunner, serve

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

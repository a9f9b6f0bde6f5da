"""A client that stops reading must not slow the others: it loses its own oldest frames, then is evicted."""

from __future__ import annotations

import socket
import time
from contextlib import contextmanager

import websocket
from svc_helpers import ScriptedRunner, serve, wait_for
from test_service_api import LiveReader


def _rate(reader: LiveReader, seconds: float) -> tuple[float, list[int]]:
    n0 = len(reader.frames)
    t0 = time.monotonic()
    time.sleep(seconds)
    frames = reader.frames[n0:]
    return len(frames) / (time.monotonic() - t0), [f.sequence for f in frames]


@contextmanager
def _fast_service(settings_factory, **settings):
    """The service over a scripted bench at 100 kS/s of 4 float32 channels (≈ 1.6 MB/s of live data): a reader
    that stops fills the socket buffers within seconds."""
    runner = ScriptedRunner(rate_hz=100_000.0, batch_s=0.01)
    with serve(settings_factory(**settings), runner=runner) as srv, srv.client() as c:
        yield srv, c


def _stalled_client(srv) -> websocket.WebSocket:
    """A live client with a tiny receive buffer that reads the schema message and then never reads again."""
    ws = websocket.create_connection(
        f"{srv.ws_base}/ws/live", timeout=10, sockopt=[(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)]
    )
    ws.recv()
    return ws


def test_stalled_client_does_not_slow_a_healthy_one(settings_factory):
    with _fast_service(settings_factory, live_queue_frames=20, live_stall_timeout_s=30.0) as (srv, c):
        healthy = LiveReader(f"{srv.ws_base}/ws/live")
        healthy.start()
        time.sleep(0.5)
        alone_rate, _ = _rate(healthy, 2.0)

        stalled = _stalled_client(srv)
        stats = wait_for(lambda: [s for s in c.get("/api/live/clients").json()["clients"] if s["dropped"] > 0],
                         timeout_s=30)
        first_dropped = stats[0]["dropped"]
        shared_rate, seqs = _rate(healthy, 2.0)
        later = [s for s in c.get("/api/live/clients").json()["clients"] if s["dropped"] > 0]
        assert later and later[0]["dropped"] > first_dropped  # it keeps losing its own oldest frames
        assert later[0]["queued"] <= 20  # bounded
        healthy.close()
        stalled.close()

    assert 20 <= alone_rate <= 30
    assert shared_rate >= 0.9 * alone_rate, (alone_rate, shared_rate)
    assert seqs == list(range(seqs[0], seqs[0] + len(seqs)))  # the healthy client lost nothing
    assert all(f.dropped == 0 for f in healthy.frames)


def test_stalled_client_is_evicted(settings_factory):
    with _fast_service(settings_factory, live_queue_frames=10, live_stall_timeout_s=1.0) as (srv, c):
        healthy = LiveReader(f"{srv.ws_base}/ws/live")
        healthy.start()
        stalled = _stalled_client(srv)
        live = wait_for(lambda: (s := c.get("/api/live/clients").json())["evicted_total"] == 1 and s, timeout_s=30)
        assert len(live["clients"]) == 1 and live["dropped_total"] > 0  # only the healthy one is left
        metrics = c.get("/metrics").text
        assert "tcms_live_evicted_clients_total 1.0" in metrics and "tcms_live_clients 1.0" in metrics
        n = len(healthy.frames)
        time.sleep(0.5)
        assert len(healthy.frames) > n  # still streaming
        healthy.close()
        stalled.close()
    seqs = [f.sequence for f in healthy.frames]
    assert seqs == list(range(seqs[0], seqs[0] + len(seqs)))

"""A client that stops reading must not slow the others: it loses its own oldest frames, then is evicted."""

from __future__ import annotations

import socket
import time
from contextlib import contextmanager

import websocket
from svc_helpers import ScriptedRunner, serve, wait_for
from test_service_api import LiveReader


def _received_during(reader: LiveReader, seconds: float) -> list[int]:
    """Sequence numbers of the frames ``reader`` received over the next ``seconds``."""
    n0 = len(reader.frames)
    time.sleep(seconds)
    return [f.sequence for f in reader.frames[n0:]]


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
    """The frame header's sequence number counts the frames the hub produced, so a healthy client that receives
    an unbroken run of sequence numbers and has nothing queued has the hub's full frame rate — judged by counts,
    not by the wall clock, so CPU load on the test machine cannot fail it."""
    with _fast_service(settings_factory, live_queue_frames=20, live_stall_timeout_s=30.0) as (srv, c):
        healthy = LiveReader(f"{srv.ws_base}/ws/live")
        healthy.start()
        alone = _received_during(healthy, 1.0)

        stalled = _stalled_client(srv)
        stats = wait_for(lambda: [s for s in c.get("/api/live/clients").json()["clients"] if s["dropped"] > 0],
                         timeout_s=30)
        first_dropped = stats[0]["dropped"]
        shared = _received_during(healthy, 2.0)
        clients = c.get("/api/live/clients").json()["clients"]
        healthy.close()
        stalled.close()

    later = [s for s in clients if s["dropped"] > 0]
    assert len(later) == 1 and later[0]["dropped"] > first_dropped  # it keeps losing its own oldest frames
    assert later[0]["queued"] <= 20  # bounded
    current = [s for s in clients if s["dropped"] == 0]
    assert len(current) == 1 and current[0]["queued"] <= 2  # the healthy client keeps up with the hub
    for seqs in (alone, shared):
        assert len(seqs) >= 5
        assert seqs == list(range(seqs[0], seqs[0] + len(seqs)))  # every frame the hub produced, none lost
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

"""Live data: the binary sample stream and the lossless event stream (WebSockets), and the clients' counters."""

from __future__ import annotations

import asyncio
import contextlib
from urllib.parse import urlsplit

from fastapi import APIRouter, WebSocket, WebSocketDisconnect

from tcms_daq.service.deps import Live
from tcms_daq.service.events import CLOSE_TRY_AGAIN_LATER, EventHub
from tcms_daq.service.live import LiveHub, schema_message
from tcms_daq.service.schemas import LiveStats

router = APIRouter(tags=["live"])


@router.get("/api/live/clients", response_model=LiveStats)
def live_clients(live: Live) -> LiveStats:
    """Frames sent, dropped and decimated, evictions, and each connected client's counters."""
    return LiveStats(sequence=live.sequence, frames_total=live.frames_total, dropped_total=live.dropped_total(),
                     samples_decimated_total=live.samples_decimated_total, evicted_total=live.evicted_total,
                     clients=live.client_stats())


async def _until_disconnect(ws: WebSocket) -> None:
    try:
        while True:
            message = await ws.receive()
            if message["type"] == "websocket.disconnect":
                return
    except (WebSocketDisconnect, RuntimeError):
        return


def _foreign_origin(ws: WebSocket) -> str | None:
    """The Origin of a browser page on another site (refused: it could read live data), else None. Clients that
    are not browsers send no Origin and are let in."""
    origin = ws.headers.get("origin")
    if origin is None or origin in ws.app.state.settings.allowed_origins:
        return None
    if urlsplit(origin).netloc.lower() == (ws.headers.get("host") or "").lower():
        return None
    return origin


@router.websocket("/ws/live")
async def ws_live(ws: WebSocket) -> None:
    live: LiveHub = ws.app.state.live
    if (origin := _foreign_origin(ws)) is not None:
        await ws.close(code=1008, reason=f"origin {origin[:80]} not allowed")
        return
    await ws.accept()
    await ws.send_json(schema_message(live.frame_rate_hz, live.max_samples_per_frame))
    client = await live.serve(ws.send_bytes, _until_disconnect(ws))
    if client.evicted:
        with contextlib.suppress(Exception):
            await asyncio.wait_for(ws.close(code=CLOSE_TRY_AGAIN_LATER, reason="stalled: evicted"), 1.0)


@router.websocket("/ws/events")
async def ws_events(ws: WebSocket) -> None:
    events: EventHub = ws.app.state.events
    since_text = ws.query_params.get("since")
    try:
        since = int(since_text) if since_text is not None else None
    except ValueError:
        await ws.close(code=1008, reason="since must be an integer")
        return
    if (origin := _foreign_origin(ws)) is not None:
        await ws.close(code=1008, reason=f"origin {origin[:80]} not allowed")
        return
    await ws.accept()
    client = await events.serve(ws.send_json, _until_disconnect(ws), since=since)
    if client.overflowed:
        with contextlib.suppress(Exception):
            await ws.close(code=CLOSE_TRY_AGAIN_LATER, reason="event backlog overflow: reconnect with ?since=")

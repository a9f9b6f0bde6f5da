"""The FastAPI application: REST under ``/api``, ``/metrics``, the live and event WebSockets and the dashboard.

``create_app(settings)`` builds the app; its lifespan opens the run store (marking runs a previous process left
active as ``interrupted``), starts the bench runner (acquisition → live hub), the live framer task and the test
manager, and tears them down in reverse order (an active test is aborted, the bench ramps down).
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any
from urllib.parse import urlsplit

from fastapi import Depends, FastAPI, HTTPException, Query, Request, WebSocket, WebSocketDisconnect
from fastapi import Path as PathParam
from fastapi.encoders import jsonable_encoder
from fastapi.exceptions import RequestValidationError
from fastapi.responses import (
    FileResponse,
    HTMLResponse,
    JSONResponse,
    PlainTextResponse,
    Response,
    StreamingResponse,
)
from fastapi.staticfiles import StaticFiles
from fastapi_offline import FastAPIOffline
from starlette.middleware.trustedhost import TrustedHostMiddleware

from tcms_daq.analysis.evaluation import jsonable
from tcms_daq.service import exports
from tcms_daq.service.auth import ReadTokenMiddleware, require_token, resolve_token
from tcms_daq.service.discrepancy_runs import DiscrepancyRuns
from tcms_daq.service.events import CLOSE_TRY_AGAIN_LATER, EventHub
from tcms_daq.service.limits import BodySizeLimit
from tcms_daq.service.live import LiveHub, schema_message
from tcms_daq.service.metrics import ServiceCollector, make_registry, render
from tcms_daq.service.report import render_report
from tcms_daq.service.runner import BenchRunner, RequestRejected, Runner
from tcms_daq.service.schemas import DiscrepancyRequest, Health, TestAccepted, TestRequest, TestSummary
from tcms_daq.service.testruns import Conflict, TestManager, UnknownRun
from tcms_daq.store import STORE_FILENAME, RunStore

STATIC_DIR = Path(__file__).parent / "static"
COMPENSATION_FILENAME = "compensation-active.toml"  # where uploads were kept before versions: imported once
DISCREPANCY_DIRNAME = "discrepancy"  # one folder per POST /api/discrepancy analysis


@dataclass
class ServiceSettings:
    """What ``tcms serve`` configures. ``sim_speed``: simulated seconds per real second."""

    data_dir: Path
    config_path: Path | None = None
    sim_speed: float = 1.0
    api_token: str | None = None
    frame_rate_hz: float = 25.0
    live_queue_frames: int = 50
    live_stall_timeout_s: float = 5.0
    live_max_samples_per_frame: int | None = 4000  # min/max decimation above this (live view only)
    recorder_flush_s: float = 0.2
    max_body_bytes: int = 1 << 20  # every request body (413 above it); a compensation TOML is a few kB
    # browsers: WebSockets accept these Origins (besides the service's own, same host:port); None = only its own
    allowed_origins: tuple[str, ...] = ()
    # Host header check against DNS rebinding; None = any host (a service bound to all interfaces)
    allowed_hosts: tuple[str, ...] | None = ("127.0.0.1", "localhost", "::1", "[::1]")
    # reads (/api/…, /ws/…, /metrics) need the token too (``tcms serve`` turns this on beyond loopback)
    read_token_required: bool = False
    extra: dict[str, Any] = field(default_factory=dict)


def _one_line_validation_error(exc: RequestValidationError) -> str:
    parts = []
    for err in exc.errors():
        loc = ".".join(str(p) for p in err.get("loc", ()) if p != "body")
        msg = str(err.get("msg", "invalid value")).removeprefix("Value error, ")  # a validator's own message
        parts.append(f"{loc}: {msg}" if loc else msg)
    return "; ".join(parts) or "invalid request"


def create_app(settings: ServiceSettings, runner: Runner | None = None) -> FastAPI:
    token, token_source = resolve_token(settings.api_token)

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        settings.data_dir.mkdir(parents=True, exist_ok=True)
        store = RunStore(settings.data_dir / STORE_FILENAME)
        bench: Runner = runner if runner is not None else await asyncio.to_thread(
            BenchRunner.from_config, settings.config_path, sim_speed=settings.sim_speed
        )
        # the compensation in use is the latest accepted version (a file from before versions is imported once)
        saved_compensation = settings.data_dir / COMPENSATION_FILENAME
        if store.compensation() is None and saved_compensation.is_file():
            await asyncio.to_thread(bench.set_compensator_toml, saved_compensation.read_text(encoding="utf-8"))
            store.add_compensation(bench.compensator_toml(), note=f"imported from {COMPENSATION_FILENAME}")
        elif (latest := store.compensation()) is not None:
            await asyncio.to_thread(bench.set_compensator_toml, latest[1])
        live = LiveHub(settings.frame_rate_hz, settings.live_queue_frames, settings.live_stall_timeout_s,
                       settings.live_max_samples_per_frame)
        events = EventHub()
        events.bind_loop(asyncio.get_running_loop())
        manager = TestManager(store, bench, events, recorder_flush_s=settings.recorder_flush_s)
        for run_id in store.recovered_run_ids:
            events.publish("test_state", id=run_id, status="interrupted", error="service restarted")
        app.state.store, app.state.runner, app.state.live = store, bench, live
        app.state.events, app.state.manager = events, manager
        app.state.discrepancy = DiscrepancyRuns(store, settings.data_dir / DISCREPANCY_DIRNAME, events)
        app.state.metrics = make_registry(ServiceCollector(live, events, store, lambda: manager.active_id))
        framer = asyncio.create_task(live.run(), name="live-framer")
        await asyncio.to_thread(bench.open, live.publish)
        try:
            yield
        finally:
            await asyncio.to_thread(manager.shutdown)
            await asyncio.to_thread(bench.close)
            framer.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await framer
            for client in tuple(live.clients):
                client.close()
            store.close()

    app = FastAPIOffline(  # /docs and /redoc from packaged assets, no CDN
        title="TCMS-DAQ",
        summary="Torsional characteristic tests of precision reducers: acquisition, live data, results.",
        version="0.1.0",
        lifespan=lifespan,
    )
    app.add_middleware(BodySizeLimit, max_bytes=settings.max_body_bytes)
    if settings.read_token_required:
        app.add_middleware(ReadTokenMiddleware, token=token)
    if settings.allowed_hosts is not None:
        app.add_middleware(TrustedHostMiddleware, allowed_hosts=list(settings.allowed_hosts))
    app.state.api_token = token
    app.state.api_token_source = token_source
    app.state.settings = settings
    auth = [Depends(require_token)]

    @app.exception_handler(RequestValidationError)
    async def _validation(request: Request, exc: RequestValidationError) -> JSONResponse:
        # jsonable: a NaN or an infinity the client sent comes back as null (strict JSON), never as a 500
        errors = jsonable(jsonable_encoder(exc.errors(), custom_encoder={Exception: str}))
        return JSONResponse({"detail": _one_line_validation_error(exc), "errors": errors}, status_code=422)

    @app.exception_handler(RequestRejected)
    async def _rejected(request: Request, exc: RequestRejected) -> JSONResponse:
        return JSONResponse({"detail": str(exc)}, status_code=422)

    @app.exception_handler(Conflict)
    async def _conflict(request: Request, exc: Conflict) -> JSONResponse:
        return JSONResponse({"detail": str(exc)}, status_code=409)

    @app.exception_handler(UnknownRun)
    async def _unknown(request: Request, exc: UnknownRun) -> JSONResponse:
        return JSONResponse({"detail": str(exc)}, status_code=404)

    def _record(request: Request, run_id: str):
        record = request.app.state.store.get_run(run_id)
        if record is None:
            raise UnknownRun(f"no test with id {run_id!r}")
        return record

    # -- REST ------------------------------------------------------------------------------------------------
    @app.get("/api/health", response_model=Health, tags=["service"])
    def health() -> dict:
        return {"status": "ok"}

    @app.get("/api/bench", tags=["bench"])
    def bench_status(request: Request) -> dict:
        state = request.app.state
        return {
            **state.runner.status(),
            "active_test": state.manager.active_id,
            "live": {
                "acquisition_rate_samples_per_second": state.live.acquisition_rate_hz(),
                "frame_rate_hz": state.live.frame_rate_hz,
                "clients": len(state.live.clients),
            },
        }

    @app.post("/api/tests", status_code=202, response_model=TestAccepted, dependencies=auth, tags=["tests"])
    def create_test(body: TestRequest, request: Request) -> dict:
        record = request.app.state.manager.submit(body)
        return {"id": record.id, "status": record.status}

    @app.get("/api/tests", response_model=list[TestSummary], tags=["tests"])
    def list_tests(
        request: Request, limit: Annotated[int, Query(ge=1, le=1000)] = 100, offset: Annotated[int, Query(ge=0, le=2**31 - 1)] = 0
    ) -> list[dict]:
        return [r.summary() for r in request.app.state.store.list_runs(limit, offset)]

    @app.get("/api/tests/{run_id}", response_model=TestSummary, tags=["tests"])
    def get_test(run_id: str, request: Request) -> dict:
        return _record(request, run_id).summary()

    @app.get("/api/tests/{run_id}/profile", tags=["tests"])
    def get_profile(run_id: str, request: Request) -> dict:
        return _record(request, run_id).profile or {}

    @app.post("/api/tests/{run_id}/abort", status_code=202, response_model=TestAccepted, dependencies=auth,
              tags=["tests"])
    def abort_test(run_id: str, request: Request) -> dict:
        record = request.app.state.manager.abort(run_id)
        return {"id": record.id, "status": "aborting"}

    @app.get("/api/tests/{run_id}/samples", tags=["tests"])
    def get_samples(
        run_id: str, request: Request,
        format: Annotated[exports.ExportFormat, Query(description="file format of the export")] = exports.ExportFormat.CSV
    ) -> Response:
        record = _record(request, run_id)
        store = request.app.state.store
        exporter, media_type, ext = exports.EXPORTERS[format]
        chunks = exports.ChunkSource(lambda: store.iter_columns(record.id))
        return StreamingResponse(
            exporter(chunks, list(record.channels), record.id), media_type=media_type,
            headers={"Content-Disposition": f'attachment; filename="tcms-{record.id}.{ext}"'},
        )

    @app.get("/api/tests/{run_id}/report", response_class=HTMLResponse, tags=["tests"])
    def get_report(run_id: str, request: Request) -> HTMLResponse:
        record = _record(request, run_id)
        return HTMLResponse(render_report(record, request.app.state.store.read_columns(record.id)))

    @app.get("/api/compensation", response_class=PlainTextResponse, tags=["compensation"])
    def get_compensation(request: Request) -> PlainTextResponse:
        """The compensator the next test will use, as TOML."""
        return PlainTextResponse(request.app.state.runner.compensator_toml(), media_type="application/toml")

    async def _activate_compensation(request: Request, text: str, note: str, rollback_of: int | None = None
                                     ) -> PlainTextResponse:
        """Check, apply and keep a compensation as the next version (422 implausible; 409 during a test)."""
        state = request.app.state
        if state.manager.active_id is not None:
            raise Conflict(f"test {state.manager.active_id} is running; change the compensation after it")
        await asyncio.to_thread(state.runner.set_compensator_toml, text)
        applied = state.runner.compensator_toml()
        version = await asyncio.to_thread(state.store.add_compensation, applied, note, rollback_of)
        state.events.publish("compensation_changed", version=version.version, note=note)
        return PlainTextResponse(applied, media_type="application/toml",
                                 headers={"X-Compensation-Version": str(version.version)})

    @app.put("/api/compensation", response_class=PlainTextResponse, dependencies=auth, tags=["compensation"],
             openapi_extra={"requestBody": {"required": True, "content": {
                 "application/toml": {"schema": {"type": "string"}}, "text/plain": {"schema": {"type": "string"}}}}})
    async def put_compensation(request: Request,
                               note: Annotated[str, Query(max_length=200)] = "") -> PlainTextResponse:
        """Replace the compensator with the TOML in the body, kept as a new version with ``note`` (422 if it
        does not parse or is not plausible; 409 during a test)."""
        raw = await request.body()
        try:
            text = raw.decode("utf-8")
        except UnicodeDecodeError:
            raise RequestRejected("compensation body is not UTF-8 TOML text") from None
        return await _activate_compensation(request, text, note)

    @app.get("/api/compensation/history", tags=["compensation"])
    def compensation_history(request: Request) -> list[dict[str, Any]]:
        """Every accepted compensation, newest first (the first is in use): version, time, note, sha256."""
        return [v.summary() for v in request.app.state.store.compensation_history()]

    @app.post("/api/compensation/rollback/{version}", response_class=PlainTextResponse, dependencies=auth,
              tags=["compensation"])
    async def rollback_compensation(version: Annotated[int, PathParam(ge=1, le=2**31 - 1)], request: Request) -> PlainTextResponse:
        """Use an earlier version again (kept as a new version that names it; 404 unknown version)."""
        found = request.app.state.store.compensation(version)
        if found is None:
            raise UnknownRun(f"no compensation version {version}")
        return await _activate_compensation(request, found[1], f"rollback to version {version}", version)

    @app.post("/api/discrepancy", status_code=201, dependencies=auth, tags=["discrepancy"])
    async def post_discrepancy(body: DiscrepancyRequest, request: Request, response: Response) -> dict:
        """Name the effects the bench model misses on a stored run (as ``tcms discrepancy --run ID --json``).

        The run's measured angle is compared with the catalogue reducer's model re-simulated on its torque
        trace. 404 unknown run; 409 while a test runs (the analysis takes seconds of CPU that acquisition must not
        lose) or another analysis runs; 422 when the run cannot be compared (too few samples, no reducer
        recorded …). The analysis is kept: ``report_url``.
        """
        active = request.app.state.manager.active_id
        if active is not None:
            raise Conflict(f"test {active} is running; find missing effects after it ends")
        doc = await asyncio.to_thread(request.app.state.discrepancy.analyse, body)
        response.headers["Location"] = f"/api/discrepancy/{doc['id']}"
        return doc

    @app.get("/api/discrepancy", tags=["discrepancy"])
    def list_discrepancy(request: Request, limit: Annotated[int, Query(ge=1, le=1000)] = 100) -> list[dict]:
        return request.app.state.discrepancy.list(limit)

    @app.get("/api/discrepancy/{analysis_id}", tags=["discrepancy"])
    def get_discrepancy(analysis_id: str, request: Request) -> dict:
        return request.app.state.discrepancy.get(analysis_id)

    @app.get("/api/discrepancy/{analysis_id}/report", response_class=HTMLResponse, tags=["discrepancy"])
    def get_discrepancy_report(analysis_id: str, request: Request) -> FileResponse:
        """The analysis report (residual before/after against time, torque and angle; the loops)."""
        return FileResponse(request.app.state.discrepancy.path(analysis_id, "report.html"), media_type="text/html")

    @app.get("/api/discrepancy/{analysis_id}/model", response_class=PlainTextResponse, tags=["discrepancy"])
    def get_discrepancy_model(analysis_id: str, request: Request) -> FileResponse:
        """The model file with the accepted terms (``tcms discrepancy`` model.toml)."""
        return FileResponse(request.app.state.discrepancy.path(analysis_id, "model.toml"),
                            media_type="application/toml")

    @app.get("/api/live/clients", tags=["live"])
    def live_clients(request: Request) -> dict:
        live: LiveHub = request.app.state.live
        return {
            "sequence": live.sequence,
            "frames_total": live.frames_total,
            "dropped_total": live.dropped_total(),
            "samples_decimated_total": live.samples_decimated_total,
            "evicted_total": live.evicted_total,
            "clients": live.client_stats(),
        }

    @app.get("/metrics", tags=["service"])
    def metrics(request: Request) -> Response:
        return Response(render(request.app.state.metrics), media_type="text/plain; version=0.0.4; charset=utf-8")

    # -- WebSockets ------------------------------------------------------------------------------------------
    async def _until_disconnect(ws: WebSocket) -> None:
        try:
            while True:
                message = await ws.receive()
                if message["type"] == "websocket.disconnect":
                    return
        except (WebSocketDisconnect, RuntimeError):
            return

    def _foreign_origin(ws: WebSocket) -> str | None:
        """The Origin of a browser page on another site (refused: it could read live data), else None.
        Clients that are not browsers send no Origin and are let in."""
        origin = ws.headers.get("origin")
        if origin is None or origin in settings.allowed_origins:
            return None
        if urlsplit(origin).netloc.lower() == (ws.headers.get("host") or "").lower():
            return None
        return origin

    @app.websocket("/ws/live")
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

    @app.websocket("/ws/events")
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

    # -- dashboard -------------------------------------------------------------------------------------------
    @app.get("/", include_in_schema=False)
    def dashboard() -> FileResponse:
        return FileResponse(STATIC_DIR / "index.html", media_type="text/html")

    app.mount("/static", StaticFiles(directory=STATIC_DIR), name="static")

    @app.exception_handler(HTTPException)
    async def _http(request: Request, exc: HTTPException) -> JSONResponse:
        return JSONResponse({"detail": exc.detail}, status_code=exc.status_code, headers=exc.headers)

    return app

"""The FastAPI application: REST under ``/api``, ``/metrics``, the live and event WebSockets and the dashboard.

``create_app(settings)`` builds the app; its lifespan opens the run store (marking runs a previous process left
active as ``interrupted``), starts the bench runner (acquisition → live hub), the live framer task and the test
manager, and tears them down in reverse order (an active test is aborted, the bench ramps down). The routes are
one router per resource (:mod:`tcms_daq.service.routes`); operation ids are the handlers' names.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

from fastapi import FastAPI, HTTPException, Request
from fastapi.encoders import jsonable_encoder
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from fastapi.routing import APIRoute
from fastapi.staticfiles import StaticFiles
from fastapi_offline import FastAPIOffline
from starlette.middleware.trustedhost import TrustedHostMiddleware

from tcms_daq.analysis.evaluation import jsonable
from tcms_daq.extras import MissingExtra
from tcms_daq.service.auth import ReadTokenMiddleware, redact_tokens_in_logs, resolve_token
from tcms_daq.service.discrepancy_runs import DiscrepancyRuns
from tcms_daq.service.events import EventHub
from tcms_daq.service.limits import BodySizeLimit
from tcms_daq.service.live import LiveHub
from tcms_daq.service.metrics import ServiceCollector, make_registry
from tcms_daq.service.routes import ROUTERS
from tcms_daq.service.routes.service import STATIC_DIR
from tcms_daq.service.runner import BenchRunner, RequestRejected, Runner
from tcms_daq.service.settings import ServiceSettings
from tcms_daq.service.signin_limit import SignInLimiter
from tcms_daq.service.te_discrepancy import DIRNAME as TE_ANALYSES_DIRNAME
from tcms_daq.service.te_discrepancy import TeAnalyses
from tcms_daq.service.testruns import Conflict, TestManager, UnknownRun
from tcms_daq.store import Store, open_store
from tcms_daq.store.base import SamplesRetired
from tcms_daq.store.discrepancy import ANALYSES_DIRNAME

__all__ = ["ServiceSettings", "create_app"]

COMPENSATION_FILENAME = "compensation-active.toml"  # where uploads were kept before versions: imported once
FROM_CONFIG = "from the bench configuration"  # the note of a compensation version the bench config supplied


def _one_line_validation_error(exc: RequestValidationError) -> str:
    parts = []
    for err in exc.errors():
        loc = ".".join(str(p) for p in err.get("loc", ()) if p != "body")
        msg = str(err.get("msg", "invalid value")).removeprefix("Value error, ")  # a validator's own message
        parts.append(f"{loc}: {msg}" if loc else msg)
    return "; ".join(parts) or "invalid request"


def _encodable(value: Any) -> Any:
    """``value`` with every string made encodable as UTF-8 (a lone surrogate a client sent is echoed as ``\\ud800``
    text, so that the answer that names it can be sent)."""
    if isinstance(value, str):
        return value.encode("utf-8", "backslashreplace").decode("utf-8")
    if isinstance(value, dict):
        return {_encodable(k): _encodable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_encodable(v) for v in value]
    return value


def _operation_id(route: APIRoute) -> str:
    return route.name


def _catalogue(runner: Runner) -> dict[str, Any]:
    """The reducer catalogue the bench runs with (its config's; the packaged one for a runner without)."""
    reducers = getattr(runner, "reducers", None)
    if isinstance(reducers, dict) and reducers:
        return reducers
    from tcms_daq.config import load_reducer_catalogue

    return dict(load_reducer_catalogue())


def bench_identity(runner: Runner) -> tuple[str, str]:
    """(id, name) of the runner's bench, from its config snapshot (``[bench] id``, else made from the name)."""
    from tcms_daq.config.models import bench_id_from_name

    section = runner.config_snapshot().get("bench") or {}
    name = str(section.get("name") or "bench")
    return str(section.get("id") or bench_id_from_name(name)), name


def compensation_in_use(bench: Runner, store: Store, saved: Path | None = None) -> int:
    """Make the compensation in use a stored version and return its number, so every run records one.

    An upload (or a rollback) stays in use over a restart. A bench whose compensation comes from its configuration
    keeps that as a version too (note :data:`FROM_CONFIG`): on the first start, and again whenever the
    configuration's compensator differs from the last one recorded from it. ``saved``: the file uploads were
    kept in before versions existed, imported once."""
    latest = store.compensation()
    if latest is None and saved is not None and saved.is_file():
        bench.set_compensator_toml(saved.read_text(encoding="utf-8"))
        return store.add_compensation(bench.compensator_toml(), note=f"imported from {saved.name}").version
    if latest is not None and not latest[0].note.startswith(FROM_CONFIG):
        bench.set_compensator_toml(latest[1])
        return latest[0].version
    configured = bench.compensator_toml()  # what the bench configuration loaded
    if latest is not None and latest[1] == configured:
        return latest[0].version
    source = str((bench.config_snapshot().get("bench") or {}).get("compensation") or "identity (no compensation)")
    return store.add_compensation(configured, note=f"{FROM_CONFIG}: {source}"[:200]).version


def create_app(settings: ServiceSettings, runner: Runner | None = None, store: Store | None = None) -> FastAPI:
    """The service. ``runner``: the bench (default: composed from ``settings.config_path``); ``store``: an open
    run store of that bench (default: opened from ``settings.store_url`` or the data directory). Both are
    closed when the app stops."""
    token, token_source = resolve_token(settings.api_token)

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        redact_tokens_in_logs()  # however the app is served: its server has configured logging by now
        settings.data_dir.mkdir(parents=True, exist_ok=True)
        bench: Runner = runner if runner is not None else await asyncio.to_thread(
            BenchRunner.from_config, settings.config_path, sim_speed=settings.sim_speed
        )
        if store is None:
            bench_id, bench_name = bench_identity(bench)
            runs: Store = await asyncio.to_thread(open_store, settings.store_url, settings.data_dir,
                                                  bench_id=bench_id, bench_name=bench_name)
        else:
            runs = store
        await _serve(app, bench, runs)
        try:
            yield
        finally:
            await _stop(app)

    async def _serve(app: FastAPI, bench: Runner, store: Store) -> None:
        await asyncio.to_thread(compensation_in_use, bench, store, settings.data_dir / COMPENSATION_FILENAME)
        live = LiveHub(settings.frame_rate_hz, settings.live_queue_frames, settings.live_stall_timeout_s,
                       settings.live_max_samples_per_frame)
        events = EventHub()
        events.bind_loop(asyncio.get_running_loop())
        manager = TestManager(store, bench, events, recorder_flush_s=settings.recorder_flush_s)
        for run_id in store.recovered_run_ids:
            events.publish("test_state", id=run_id, status="interrupted", error="service restarted")
        app.state.store, app.state.runner, app.state.live = store, bench, live
        app.state.events, app.state.manager = events, manager
        app.state.discrepancy = DiscrepancyRuns(store, settings.data_dir / ANALYSES_DIRNAME, events)
        app.state.te_discrepancy = TeAnalyses(store, settings.data_dir / TE_ANALYSES_DIRNAME, _catalogue(bench),
                                              getattr(bench, "config", None), events)
        app.state.metrics = make_registry(ServiceCollector(live, events, store, lambda: manager.active_id))
        app.state.framer = asyncio.create_task(live.run(), name="live-framer")
        app.state.opcua = None
        sink = live.publish
        if settings.opcua_port is not None:
            from tcms_daq.service.opcua import OpcUaBridge

            fallback_id, fallback_name = bench_identity(bench)
            configured = getattr(getattr(bench, "config", None), "opcua", None)
            section = bench.config_snapshot().get("bench")
            opcua = OpcUaBridge(store, store.bench_id or fallback_id, store.bench_name or fallback_name,
                                settings.opcua_port, config=settings.opcua or configured, data_dir=settings.data_dir,
                                nameplate=section if isinstance(section, dict) else None,
                                bench_connected=lambda: bench.status().get("connected"))
            events.add_listener(opcua.on_event)
            await asyncio.to_thread(opcua.start)
            app.state.opcua = opcua
            print(f"OPC UA server on {opcua.endpoint} (bench {opcua.bench_id})", flush=True)

            def sink(columns: Any) -> None:  # the acquisition thread: the live hub, then a reference for OPC UA
                live.publish(columns)
                opcua.live(columns)

        await asyncio.to_thread(bench.open, sink)
        safe_start = getattr(bench, "safe_start", None)
        report = safe_start() if safe_start is not None else None
        if report is not None:  # what the bench's safe start found on the loader and did about it
            events.publish("bench_safe_start", **report)

    async def _stop(app: FastAPI) -> None:
        state = app.state
        await asyncio.to_thread(state.manager.shutdown)
        await asyncio.to_thread(state.runner.close)
        if state.opcua is not None:
            await asyncio.to_thread(state.opcua.stop)
        state.framer.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await state.framer
        for client in tuple(state.live.clients):
            client.close()
        await asyncio.to_thread(state.store.close)

    app = FastAPIOffline(  # /docs and /redoc from packaged assets, no CDN
        title="TCMS-DAQ",
        summary="Torsional characteristic tests of precision reducers: acquisition, live data, results.",
        version="0.1.0",
        lifespan=lifespan,
        generate_unique_id_function=_operation_id,
    )
    app.add_middleware(BodySizeLimit, max_bytes=settings.max_body_bytes)
    if settings.read_token_required:
        app.add_middleware(ReadTokenMiddleware, token=token)
    if settings.allowed_hosts is not None:
        app.add_middleware(TrustedHostMiddleware, allowed_hosts=list(settings.allowed_hosts))
    app.state.api_token = token
    app.state.api_token_source = token_source
    app.state.settings = settings
    app.state.signin_limiter = SignInLimiter()

    @app.exception_handler(RequestValidationError)
    async def _validation(request: Request, exc: RequestValidationError) -> JSONResponse:
        # jsonable: a NaN or an infinity the client sent comes back as null (strict JSON), never as a 500
        errors = _encodable(jsonable(jsonable_encoder(exc.errors(), custom_encoder={Exception: str})))
        return JSONResponse({"detail": _encodable(_one_line_validation_error(exc)), "errors": errors},
                            status_code=422)

    @app.exception_handler(RequestRejected)
    async def _rejected(request: Request, exc: RequestRejected) -> JSONResponse:
        return JSONResponse({"detail": str(exc)}, status_code=422)

    @app.exception_handler(Conflict)
    async def _conflict(request: Request, exc: Conflict) -> JSONResponse:
        return JSONResponse({"detail": str(exc)}, status_code=409)

    @app.exception_handler(SamplesRetired)
    async def _retired(request: Request, exc: SamplesRetired) -> JSONResponse:
        return JSONResponse({"detail": str(exc)}, status_code=410)

    @app.exception_handler(MissingExtra)
    async def _missing_extra(request: Request, exc: MissingExtra) -> JSONResponse:
        return JSONResponse({"detail": str(exc)}, status_code=501)

    @app.exception_handler(UnknownRun)
    async def _unknown(request: Request, exc: UnknownRun) -> JSONResponse:
        return JSONResponse({"detail": str(exc)}, status_code=404)

    for router in ROUTERS:
        app.include_router(router)
    app.mount("/static", StaticFiles(directory=STATIC_DIR), name="static")

    @app.exception_handler(HTTPException)
    async def _http(request: Request, exc: HTTPException) -> JSONResponse:
        return JSONResponse({"detail": exc.detail}, status_code=exc.status_code, headers=exc.headers)

    return app

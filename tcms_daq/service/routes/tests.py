"""Tests: start, list, one, its profile, abort, sample exports (streamed) and the HTML report."""

from __future__ import annotations

import json
from datetime import UTC, datetime
from typing import Annotated, Any, Literal

import numpy as np
from fastapi import APIRouter, Depends, HTTPException, Query, Request, Response
from fastapi.responses import HTMLResponse, JSONResponse, StreamingResponse
from pydantic import TypeAdapter

from tcms_daq.analysis.evaluation import jsonable
from tcms_daq.extras import require_extra
from tcms_daq.service import exports
from tcms_daq.service.admin_settings import stored_settings
from tcms_daq.service.auth import AUTOMATION, Principal, require
from tcms_daq.service.deps import Manager, RunWithSamplesDep, Store, StoredRunDep, errors
from tcms_daq.service.messages import language
from tcms_daq.service.report import render_report
from tcms_daq.service.runner import RequestRejected
from tcms_daq.service.schemas import ErrorBody, LoopView, TestAccepted, TestRequest, TestSummary, summary_view
from tcms_daq.service.users import audit
from tcms_daq.store import RunQuery, StoreError
from tcms_daq.store.base import EXACT_TOTAL_UP_TO, text_sha256
from tcms_daq.store.people import SavedPlan

router = APIRouter(prefix="/api/tests", tags=["tests"])

Lang = Annotated[Literal["en", "zh", "zh-CN"] | None, Query(description="language of the words: en, zh")]
MEDIA_TYPES = {fmt: media for fmt, (_, media, _) in exports.EXPORTERS.items()}


@router.post("", status_code=202, response_model=TestAccepted, responses=errors(401, 403, 409, 413, 422))
def create_test(body: TestRequest, manager: Manager, store: Store,
                who: Annotated[Principal, Depends(require("test.start"))]) -> TestAccepted:
    """Queue a test (an engineer's right; an operator starts saved plans: ``POST /api/tests/from-plan``); 422
    when it leaves the bench's or the reducer's bounds, 409 while another test runs."""
    return start_test(manager, store, who, body)


def start_test(manager: Manager, store: Store, who: Principal, request: TestRequest,
               plan: SavedPlan | None = None) -> TestAccepted:
    """The one way a test starts (a free request or a saved plan's): queued by the manager with its user and
    plan, audited."""
    plan_ref = None if plan is None else {"id": plan.id, "name": plan.name, "version": plan.version}
    record = manager.submit(request, user=who.name, plan_ref=plan_ref)
    audit(store, who, "test.start", target=record.id,
          after=f"plan {plan.name} v{plan.version}" if plan is not None else
          f"request sha256 {text_sha256(json.dumps(record.request, sort_keys=True))[:16]}",
          detail=f"{request.reducer}, serial {request.serial_number or '—'}")
    return TestAccepted(id=record.id, status=record.status)


StoredStatus = Literal["queued", "running", "completed", "aborted", "failed", "interrupted"]
_Text = Annotated[str | None, Query(min_length=1, max_length=200)]


def unix_seconds(t: datetime | None) -> float | None:
    """An ISO 8601 instant as UNIX seconds; without a zone it is UTC."""
    if t is None:
        return None
    return (t if t.tzinfo is not None else t.replace(tzinfo=UTC)).timestamp()


def run_query(bench: _Text = None, reducer: _Text = None, serial: _Text = None, status: StoredStatus | None = None,
              verdict: Literal["pass", "fail", "undecided"] | None = None, q: _Text = None,
              since: Annotated[datetime | None, Query(description="created at or after (ISO 8601; UTC without a zone)")] = None,
              until: Annotated[datetime | None, Query(description="created at or before (ISO 8601; UTC without a zone)")] = None,
              ) -> RunQuery:
    """The filters of ``GET /api/tests`` (and of the SPC views): 422 with one line when they contradict."""
    try:
        return RunQuery(bench=bench, reducer=reducer, serial=serial, status=status, verdict=verdict, text=q,
                        since=unix_seconds(since), until=unix_seconds(until))
    except StoreError as exc:
        raise RequestRejected(str(exc)) from None


@router.get("", response_model=list[TestSummary], responses={
    **errors(422), 200: {"description": "the page of tests, newest first",
                         "headers": {"X-Total-Count": {"description": "tests matching the filters, all pages (an "
                                                                      "estimate when X-Total-Count-Exact is false)",
                                                       "schema": {"type": "integer"}},
                                     "X-Total-Count-Exact": {"description": (
                                         f"false when more than {EXACT_TOTAL_UP_TO} tests match and the store "
                                         "(PostgreSQL) gives its estimate instead of counting them all"),
                                         "schema": {"type": "boolean"}}}}})
def list_tests(store: Store, query: Annotated[RunQuery, Depends(run_query)],
               limit: Annotated[int, Query(ge=1, le=1000)] = 100,
               offset: Annotated[int, Query(ge=0, le=2**31 - 1)] = 0,
               brief: Annotated[bool, Query(description=(
                   "each test's results reduced to its headline results (with their uncertainty) and verdict, as "
                   "the fleet page lists them: a page of a plant's runs without their whole results"))] = False,
               ) -> Response:
    """Stored tests of every bench sharing the store, newest first, one page at a time (``limit``, ``offset``;
    the header ``X-Total-Count`` counts all pages, exactly up to a limit; past it PostgreSQL estimates and
    ``X-Total-Count-Exact`` says ``false``). Filters: ``bench`` (id or name), ``reducer`` and ``serial``
    (exact, any case), ``status``, ``verdict`` (pass / fail / undecided), ``q`` (a substring of the id, serial
    number, reducer, operator or bench), ``since`` / ``until`` (creation time, ISO 8601). ``brief``: results reduced
    to the headline results and the verdict."""
    total = store.total_runs(query)
    views = [summary_view(r.summary()) for r in store.list_runs(limit, offset, query, brief=brief)]
    # the views are validated models already: serialised once by pydantic (FastAPI would validate them again and
    # encode them in Python, more than the query costs for a page of a plant's runs)
    return Response(_SUMMARIES.dump_json(views), media_type="application/json", headers={
        "X-Total-Count": str(total.count), "X-Total-Count-Exact": "true" if total.exact else "false"})


_SUMMARIES = TypeAdapter(list[TestSummary])


@router.get("/{run_id}", response_model=TestSummary, responses=errors(404))
def get_test(run: StoredRunDep) -> TestSummary:
    """One test: its request, status, results (headline results with unit and U) and where it ran."""
    return summary_view(run.summary())


@router.get("/{run_id}/profile", response_model=dict[str, Any], responses=errors(404))
def get_profile(run: StoredRunDep) -> dict[str, Any]:
    """The loading profile the test ran (segments, rates, dwell), as built from its request."""
    return run.profile or {}


@router.post("/{run_id}/abort", status_code=202, response_model=TestAccepted, responses=errors(401, 403, 404, 409))
def abort_test(run_id: str, manager: Manager, store: Store,
               who: Annotated[Principal, Depends(require("test.abort"))]) -> TestAccepted:
    """Ramp down from the measured torque and disable the drive (within the bench's stop bound)."""
    record = manager.abort(run_id, reason="aborted by the operator" + (
        f" ({who.name})" if who.role != AUTOMATION else ""))
    audit(store, who, "test.abort", target=run_id, before=record.status, after="aborting")
    return TestAccepted(id=record.id, status="aborting")


@router.get("/{run_id}/samples", response_class=StreamingResponse, responses={
    **errors(404, 410, 422, 501), 200: {"description": "the run's samples as a file", "content": {
        media: {"schema": {"type": "string", "format": "binary"}} for media in MEDIA_TYPES.values()}}})
def get_samples(run: RunWithSamplesDep, store: Store, format: Annotated[
        exports.ExportFormat, Query(description="file format of the export")] = exports.ExportFormat.CSV
                ) -> StreamingResponse:
    """Every recorded sample (canonical columns first), streamed from the store chunk by chunk."""
    if format == exports.ExportFormat.MDF4:
        require_extra("exports", "the MDF4 export")
    exporter, media_type, ext = exports.EXPORTERS[format]
    chunks = exports.ChunkSource(lambda: store.iter_columns(run.id))
    headers = {"Content-Disposition": f'attachment; filename="tcms-{run.id}.{ext}"'}
    if format == exports.ExportFormat.CSV:  # its identity is in the sidecar
        headers["Link"] = f'</api/tests/{run.id}/metadata>; rel="describedby"; type="application/json"'
    return StreamingResponse(exporter(chunks, list(run.channels), exports.ExportMeta.of(run)),
                             media_type=media_type, headers=headers)


@router.get("/{run_id}/metadata", response_model=dict[str, Any], responses=errors(404, 410))
def get_metadata(run: RunWithSamplesDep, store: Store) -> JSONResponse:
    """The sample CSV's sidecar (``tcms-<id>.json``): the test's identity (reducer, serial number, bench,
    operator, parameters, compensation version, results ± U, verdict), its start time and full results; the
    same as the Parquet schema metadata and the MDF4 header carry."""
    doc = exports.sidecar(exports.ExportMeta.of(run), store.iter_columns(run.id, chunk_samples=1), run.channels)
    return JSONResponse(jsonable(doc), headers={"Content-Disposition": f'inline; filename="tcms-{run.id}.json"'})


@router.get("/{run_id}/certificate.pdf", response_class=Response, responses={
    **errors(404, 410), 503: {"model": ErrorBody, "description": "the language needs a font the service lacks"},
    200: {"description": "the test certificate", "content": {"application/pdf": {
        "schema": {"type": "string", "format": "binary"}}}}})
def get_certificate(run: RunWithSamplesDep, store: Store, request: Request, lang: Lang = None) -> Response:
    """The PDF test certificate: identity, parameters, the loop, results ± U with the decision rule, the verdict,
    the instruments with their calibration and the compensation version (``tcms certificate`` writes the same).
    ``lang``: en or zh (default: the bench's default language, else the browser's Accept-Language, else
    English)."""
    from tcms_daq.service.certificate import MissingFont, render_certificate

    try:
        pdf = render_certificate(run, store.read_columns(run.id),
                                 lang=language(lang, request.headers.get("accept-language"),
                                              stored_settings(store).default_language))
    except MissingFont as exc:
        raise HTTPException(status_code=503, detail=str(exc)) from None
    return Response(pdf, media_type="application/pdf",
                    headers={"Content-Disposition": f'inline; filename="tcms-certificate-{run.id}.pdf"'})


@router.get("/{run_id}/report", response_class=HTMLResponse, responses=errors(404, 410))
def get_report(run: RunWithSamplesDep, store: Store, request: Request, lang: Lang = None) -> HTMLResponse:
    """A self-contained HTML report: the loop, the results and the verdict. ``lang``: en or zh (default: the
    bench's default language, else the browser's Accept-Language, else English)."""
    return HTMLResponse(render_report(run, store.read_columns(run.id),
                                      lang=language(lang, request.headers.get("accept-language"),
                                                   stored_settings(store).default_language)))


@router.get("/{run_id}/curves", response_model=dict[str, Any], responses=errors(404, 410))
def get_curves(run: RunWithSamplesDep, store: Store) -> JSONResponse:
    """What a turning test's figure draws (``tcms_daq.service.method_views.method_curves``): the transmission
    error against the output angle per direction with its order spectrum and lines (order, component, amplitude ±
    U, phase); each starting-torque ramp around its breakaway (input torque and angle against the time from the
    onset); the no-load torque per speed; the efficiency per direction with its blocks. ``{"method":
    "stiffness"}`` for a stiffness test (its loop: ``/loop``)."""
    from tcms_daq.service.method_views import method_curves, method_of

    columns = store.read_columns(run.id) if method_of(run.results) == "starting-torque" else None
    return JSONResponse(jsonable(method_curves(run.results, columns)))


@router.get("/{run_id}/loop", response_model=LoopView, responses=errors(404, 410, 422))
def get_loop(run: RunWithSamplesDep, store: Store,
             max_points: Annotated[int, Query(ge=100, le=100_000)] = 4000) -> dict[str, Any]:
    """The run's hysteresis loop (torque and compensated angle) for plotting, at most ``max_points`` measured
    pairs: per bucket the samples holding the extremes of torque and angle, in time order."""
    from tcms_daq.service.live import minmax_rows

    cols = store.read_columns(run.id)
    torque, angle = cols.get("torque_nm"), cols.get("angle_arcsec")
    if torque is None or angle is None or not len(torque):
        return {"id": run.id, "samples": 0, "torque_nm": [], "angle_arcsec": []}
    rows = minmax_rows({"time_s": cols.get("time_s", torque), "torque_nm": torque, "angle_arcsec": angle}, max_points)
    if rows is not None:
        torque, angle = torque[rows], angle[rows]
    finite = [bool(v) for v in (np.isfinite(torque) & np.isfinite(angle))]
    return {"id": run.id, "samples": int(len(cols["torque_nm"])),
            "torque_nm": [float(v) for v, ok in zip(torque, finite, strict=True) if ok],
            "angle_arcsec": [float(v) for v, ok in zip(angle, finite, strict=True) if ok]}

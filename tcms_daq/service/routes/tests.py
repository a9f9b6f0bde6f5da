"""Tests: start, list, one, its profile, abort, sample exports (streamed) and the HTML report."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Query
from fastapi.responses import HTMLResponse, StreamingResponse

from tcms_daq.service import exports
from tcms_daq.service.deps import AUTH, Manager, Store, StoredRunDep, errors
from tcms_daq.service.report import render_report
from tcms_daq.service.schemas import TestAccepted, TestRequest, TestSummary

router = APIRouter(prefix="/api/tests", tags=["tests"])

MEDIA_TYPES = {fmt: media for fmt, (_, media, _) in exports.EXPORTERS.items()}


@router.post("", status_code=202, response_model=TestAccepted, dependencies=AUTH,
             responses=errors(401, 409, 413, 422))
def create_test(body: TestRequest, manager: Manager) -> TestAccepted:
    """Queue a test; 422 when it leaves the bench's or the reducer's bounds, 409 while another test runs."""
    record = manager.submit(body)
    return TestAccepted(id=record.id, status=record.status)


@router.get("", response_model=list[TestSummary], responses=errors(422))
def list_tests(store: Store, limit: Annotated[int, Query(ge=1, le=1000)] = 100,
               offset: Annotated[int, Query(ge=0, le=2**31 - 1)] = 0) -> list[dict[str, Any]]:
    """Stored tests, newest first."""
    return [r.summary() for r in store.list_runs(limit, offset)]


@router.get("/{run_id}", response_model=TestSummary, responses=errors(404))
def get_test(run: StoredRunDep) -> dict[str, Any]:
    return run.summary()


@router.get("/{run_id}/profile", response_model=dict[str, Any], responses=errors(404))
def get_profile(run: StoredRunDep) -> dict[str, Any]:
    """The loading profile the test ran (segments, rates, dwell), as built from its request."""
    return run.profile or {}


@router.post("/{run_id}/abort", status_code=202, response_model=TestAccepted, dependencies=AUTH,
             responses=errors(401, 404, 409))
def abort_test(run_id: str, manager: Manager) -> TestAccepted:
    """Ramp down from the measured torque and disable the drive (within the bench's stop bound)."""
    record = manager.abort(run_id)
    return TestAccepted(id=record.id, status="aborting")


@router.get("/{run_id}/samples", response_class=StreamingResponse, responses={
    **errors(404, 422), 200: {"description": "the run's samples as a file", "content": {
        media: {"schema": {"type": "string", "format": "binary"}} for media in MEDIA_TYPES.values()}}})
def get_samples(run: StoredRunDep, store: Store, format: Annotated[
        exports.ExportFormat, Query(description="file format of the export")] = exports.ExportFormat.CSV
                ) -> StreamingResponse:
    """Every recorded sample (canonical columns first), streamed from the store chunk by chunk."""
    exporter, media_type, ext = exports.EXPORTERS[format]
    chunks = exports.ChunkSource(lambda: store.iter_columns(run.id))
    return StreamingResponse(
        exporter(chunks, list(run.channels), run.id), media_type=media_type,
        headers={"Content-Disposition": f'attachment; filename="tcms-{run.id}.{ext}"'},
    )


@router.get("/{run_id}/report", response_class=HTMLResponse, responses=errors(404))
def get_report(run: StoredRunDep, store: Store) -> HTMLResponse:
    """A self-contained HTML report: the loop, the results and the verdict."""
    return HTMLResponse(render_report(run, store.read_columns(run.id)))

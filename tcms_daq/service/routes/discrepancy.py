"""Discrepancy analyses of stored runs: run one, list them, one, its report and its model file."""

from __future__ import annotations

import asyncio
from typing import Annotated, Any

from fastapi import APIRouter, Depends, Query, Response
from fastapi.responses import FileResponse, HTMLResponse, PlainTextResponse

from tcms_daq.service.auth import Principal, require
from tcms_daq.service.deps import Analyses, Manager, Store, errors
from tcms_daq.service.schemas import (
    ApplyRequest,
    BenchModelView,
    DiscrepancyAnalysis,
    DiscrepancyListItem,
    DiscrepancyRequest,
)
from tcms_daq.service.testruns import Conflict
from tcms_daq.service.users import audit

router = APIRouter(prefix="/api/discrepancy", tags=["discrepancy"])
model_router = APIRouter(prefix="/api/model", tags=["discrepancy"])


@router.post("", status_code=201, response_model=DiscrepancyAnalysis,
             dependencies=[Depends(require("discrepancy.run"))], responses=errors(401, 403, 404, 409, 413, 422))
async def post_discrepancy(body: DiscrepancyRequest, response: Response, manager: Manager,
                           analyses: Analyses) -> dict[str, Any]:
    """Name the effects the bench model misses on a stored run (as ``tcms discrepancy --run ID --json``).

    The run's measured angle is compared with the catalogue reducer's model re-simulated on its torque trace.
    404 unknown run; 409 while a test runs (the analysis takes seconds of CPU that acquisition must not lose) or
    another analysis runs; 422 when the run cannot be compared (too few samples, no reducer recorded …). The
    analysis is kept: ``report_url``.
    """
    if manager.active_id is not None:
        raise Conflict(f"test {manager.active_id} is running; find missing effects after it ends")
    doc = await asyncio.to_thread(analyses.analyse, body)
    response.headers["Location"] = f"/api/discrepancy/{doc['id']}"
    return doc


@router.get("", response_model=list[DiscrepancyListItem], responses=errors(422))
def list_discrepancy(analyses: Analyses,
                     limit: Annotated[int, Query(ge=1, le=1000)] = 100) -> list[dict[str, Any]]:
    """Finished analyses, newest first: the effects named and the held-out RMS before and after."""
    return analyses.list(limit)


@router.get("/{analysis_id}", response_model=DiscrepancyAnalysis, responses=errors(404))
def get_discrepancy(analysis_id: str, analyses: Analyses) -> dict[str, Any]:
    """One analysis: the effects named with their parameters, aliases, the residual before and after."""
    return analyses.get(analysis_id)


@router.get("/{analysis_id}/report", response_class=HTMLResponse, responses=errors(404))
def get_discrepancy_report(analysis_id: str, analyses: Analyses) -> FileResponse:
    """The analysis report (residual before/after against time, torque and angle; the loops)."""
    return FileResponse(analyses.path(analysis_id, "report.html"), media_type="text/html")


@router.get("/{analysis_id}/model", response_class=PlainTextResponse, responses={
    **errors(404), 200: {"content": {"application/toml": {"schema": {"type": "string"}}}}})
def get_discrepancy_model(analysis_id: str, analyses: Analyses) -> FileResponse:
    """The model file with the accepted terms (``tcms discrepancy`` model.toml)."""
    return FileResponse(analyses.path(analysis_id, "model.toml"), media_type="application/toml")


@router.post("/{analysis_id}/apply", response_model=BenchModelView, responses=errors(401, 403, 404, 409, 413, 422))
def apply_discrepancy(analysis_id: str, analyses: Analyses, store: Store,
                      who: Annotated[Principal, Depends(require("bench_model.apply"))],
                      body: ApplyRequest | None = None) -> dict[str, Any]:
    """Add the effects an analysis named to the bench model, as its next version; the next analysis compares
    against it. 404 unknown analysis; 409 when the analysis was made against an older version (analyse the run
    again) or its names are provisional and ``accept_provisional`` is not set; 422 when it named nothing."""
    before = store.bench_model()
    view = analyses.apply(analysis_id, accept_provisional=bool(body and body.accept_provisional))
    after = store.bench_model()
    audit(store, who, "bench_model.apply", target=analysis_id,
          before=f"v{before[0].version}" if before else "v0",
          after=f"v{after[0].version} sha256 {after[0].sha256[:16]}" if after else None)
    return view


@model_router.get("", response_model=BenchModelView)
def get_bench_model(analyses: Analyses) -> dict[str, Any]:
    """The bench model in use (the catalogue reducer's model plus the accepted effects) and its versions with
    their provenance (which analysis of which run added what)."""
    return analyses.model()

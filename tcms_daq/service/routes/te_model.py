"""The transmission error's discrepancy workflow (``tcms_daq.service.te_discrepancy``): analyse a stored
transmission-error run against its unit's TE model, apply what it named as the model's next version, read the
model and its history."""

from __future__ import annotations

import asyncio
from typing import Annotated, Any

from fastapi import APIRouter, Depends, Query, Response

from tcms_daq.service.auth import Principal, require
from tcms_daq.service.deps import Manager, Store, TeAnalysesDep, errors
from tcms_daq.service.schemas import TeDiscrepancyAnalysis, TeDiscrepancyRequest, TeModelView
from tcms_daq.service.testruns import Conflict
from tcms_daq.service.users import audit

router = APIRouter(prefix="/api/te-discrepancy", tags=["discrepancy"])
model_router = APIRouter(prefix="/api/te-model", tags=["discrepancy"])


@router.post("", status_code=201, response_model=TeDiscrepancyAnalysis,
             dependencies=[Depends(require("discrepancy.run"))], responses=errors(401, 403, 404, 409, 413, 422))
async def post_te_discrepancy(body: TeDiscrepancyRequest, response: Response, manager: Manager,
                              analyses: TeAnalysesDep) -> dict[str, Any]:
    """Compare a stored transmission-error run with its unit's TE model: each line the model lacks named by its
    order and the component at that order (or by its order alone), held against what the measuring chain alone
    can make there; the verdict ``consistent`` | ``explained`` | ``partially_explained`` | ``unexplained``.
    404 unknown run; 409 while a test runs or another analysis runs; 422 not a completed transmission-error run."""
    if manager.active_id is not None:
        raise Conflict(f"test {manager.active_id} is running; analyse the transmission error after it ends")
    doc = await asyncio.to_thread(analyses.analyse, body.run_id)
    response.headers["Location"] = f"/api/te-discrepancy/{doc['id']}"
    return doc


@router.get("/{analysis_id}", response_model=TeDiscrepancyAnalysis, responses=errors(404))
def get_te_discrepancy(analysis_id: str, analyses: TeAnalysesDep) -> dict[str, Any]:
    """One TE discrepancy analysis."""
    return analyses.get(analysis_id)


@router.post("/{analysis_id}/apply", response_model=TeModelView, responses=errors(401, 403, 404, 409, 422))
def apply_te_discrepancy(analysis_id: str, analyses: TeAnalysesDep, store: Store,
                         who: Annotated[Principal, Depends(require("bench_model.apply"))]) -> dict[str, Any]:
    """Add the lines an analysis named to its unit's TE model, as the model's next version (the next analysis
    compares against it). 404 unknown analysis; 409 made against an older version; 422 it named nothing."""
    doc = analyses.get(analysis_id)
    before = analyses.model_for(doc["reducer"])[0]
    view = analyses.apply(analysis_id)
    audit(store, who, "te_model.apply", target=analysis_id, before=f"v{before}",
          after=f"v{view['version']} ({doc['reducer']})")
    return view


@model_router.get("", response_model=TeModelView, responses=errors(422))
def get_te_model(analyses: TeAnalysesDep,
                 reducer: Annotated[str, Query(min_length=1, max_length=64, description="the reducer type")]
                 ) -> dict[str, Any]:
    """A reducer type's TE model in use (version 0: the catalogue's harmonics) and the TE model history."""
    return analyses.model(reducer)

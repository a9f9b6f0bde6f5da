"""The compensation in use: read it, upload a new version (checked for plausibility), history, rollback."""

from __future__ import annotations

import asyncio
import math
from collections.abc import Callable
from typing import Annotated, Any

from fastapi import APIRouter, Depends, Query, Request
from fastapi import Path as PathParam
from fastapi.responses import JSONResponse, PlainTextResponse, Response

from tcms_daq.compensation.plausibility import (
    ReferenceLoop,
    UploadJudgement,
    judge_upload,
    synthetic_reference,
)
from tcms_daq.service.auth import Principal, require
from tcms_daq.service.deps import Bench, Events, Manager, Store, errors
from tcms_daq.service.runner import RequestRejected
from tcms_daq.service.schemas import CompensationDryRun, CompensationVersion
from tcms_daq.service.testruns import Conflict, UnknownRun
from tcms_daq.service.users import audit
from tcms_daq.store.base import CompensationVersion as StoredVersion
from tcms_daq.store.compensation import (
    Apply,
    CompensationRejected,
    CompensationVersions,
    FromModel,
    UnknownVersion,
)

router = APIRouter(prefix="/api/compensation", tags=["compensation"])

# The body is read as bytes whatever its Content-Type: TOML text, declared as application/toml (its media type,
# RFC 9618) and as application/octet-stream, which client generators (openapi-python-client) know as a file body
TOML_BODY = {"requestBody": {"required": True, "description": "the compensator as UTF-8 TOML ([compensator] terms)",
                             "content": {"application/toml": {"schema": {"type": "string"}},
                                         "application/octet-stream": {"schema": {"type": "string",
                                                                                 "format": "binary"}}}}}
TOML_ANSWER: dict[int | str, dict[str, Any]] = {200: {"description": "the compensator now in use, as TOML (header X-Compensation-Version)",
                     "content": {"application/toml": {"schema": {"type": "string"}}}}}


@router.get("", response_class=PlainTextResponse,
            responses={200: {"content": {"application/toml": {"schema": {"type": "string"}}}}})
def get_compensation(bench: Bench) -> PlainTextResponse:
    """The compensator the next test will use, as TOML."""
    return PlainTextResponse(bench.compensator_toml(), media_type="application/toml")


async def _activate(bench: Bench, manager: Manager, store: Store, events: Events,
                    change: Callable[[Apply], StoredVersion], who: Principal, action: str) -> PlainTextResponse:
    """Make a compensation version (``change``, :class:`CompensationVersions`), applied to the bench first
    (422 implausible, 404 unknown version, 409 during a test); audited as ``action`` with the version and hash
    before and after."""
    if manager.active_id is not None:
        raise Conflict(f"test {manager.active_id} is running; change the compensation after it")
    previous = store.compensation()

    def apply(text: str) -> str:
        bench.set_compensator_toml(text)
        return bench.compensator_toml()

    try:
        version = await asyncio.to_thread(change, apply)
    except CompensationRejected as exc:
        raise RequestRejected(str(exc)) from None
    except UnknownVersion as exc:
        raise UnknownRun(str(exc)) from None
    events.publish("compensation_changed", version=version.version, note=version.note)
    audit(store, who, action, target="compensation",
          before=None if previous is None else f"v{previous[0].version} sha256 {previous[0].sha256[:16]}",
          after=f"v{version.version} sha256 {version.sha256[:16]}", detail=version.note or None)
    return PlainTextResponse(bench.compensator_toml(), media_type="application/toml",
                             headers={"X-Compensation-Version": str(version.version)})


@router.put("", response_class=PlainTextResponse, openapi_extra=TOML_BODY,
            responses={**TOML_ANSWER, **errors(401, 403, 409, 413, 422),
                       202: {"description": "dry run: what the upload would do (nothing stored)",
                             "model": CompensationDryRun}})
async def put_compensation(request: Request, bench: Bench, manager: Manager, store: Store, events: Events,
                           who: Annotated[Principal, Depends(require("compensation.edit"))],
                           note: Annotated[str, Query(max_length=200)] = "",
                           dry_run: Annotated[bool, Query(description="judge the upload, store nothing")] = False,
                           force: Annotated[bool, Query(description="accept a rigidity change beyond the band")]
                           = False) -> Response:
    """Replace the compensator with the TOML in the body, kept as a new version with ``note``. The body is held
    to a closed schema and to the bench's bands per term type (422 naming the problem), and to the change it makes
    to the rigidity of a reference record (the last completed run, else a synthetic loop): beyond the band it is
    refused (422) unless ``force=true``. ``dry_run=true`` answers 202 with that change and stores nothing.
    409 during a test."""
    raw = await request.body()
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        raise RequestRejected("compensation body is not UTF-8 TOML text") from None
    judgement = await asyncio.to_thread(_judge, bench, store, text)
    if judgement.problems:
        raise RequestRejected(judgement.reason())
    if dry_run:
        change = judgement.rigidity_change
        body = CompensationDryRun(
            reference=judgement.reference, refused=judgement.refused or None,
            rigidity_change_pct=None if change is None or not math.isfinite(change) else round(100.0 * change, 4))
        return JSONResponse(body.model_dump(), status_code=202)
    if judgement.refused and not force:
        raise RequestRejected(judgement.refused)
    return await _activate(bench, manager, store, events,
                           lambda apply: CompensationVersions(store).upload(text, note, apply=apply), who,
                           "compensation.upload")


def _judge(bench: Bench, store: Store, text: str) -> UploadJudgement:
    """The upload judged against the compensation in use on the last completed run of this bench (else a
    synthetic loop up to the bench's max torque)."""
    from tcms_daq.compensation.compensator import Compensator
    from tcms_daq.store.base import RunQuery

    checks = bench.compensation_checks()
    current = Compensator.loads(bench.compensator_toml(), "the compensation in use")
    reference = None
    last = store.list_runs(limit=1, query=RunQuery(status="completed", bench=store.bench_id or None))
    if last:
        reference = ReferenceLoop.from_columns(store.read_columns(last[0].id), f"last completed run {last[0].id}")
    if reference is None:
        max_torque = float(bench.status().get("max_torque_nm") or 1000.0)
        reference = synthetic_reference(current, max_torque, checks.synthetic_rigidity_nm_per_arcmin)
    return judge_upload(text, current, reference, checks)


@router.get("/history", response_model=list[CompensationVersion])
def compensation_history(store: Store) -> list[dict]:
    """Every accepted compensation, newest first (the first is in use): version, time, note, sha256."""
    return [v.summary() for v in CompensationVersions(store).history()]


@router.post("/rollback/{version}", response_class=PlainTextResponse,
             responses={**TOML_ANSWER, **errors(401, 403, 404, 409, 422)})
async def rollback_compensation(version: Annotated[int, PathParam(ge=1, le=2**31 - 1)], bench: Bench,
                                manager: Manager, store: Store, events: Events,
                                who: Annotated[Principal, Depends(require("compensation.edit"))]
                                ) -> PlainTextResponse:
    """Use an earlier version again (kept as a new version that names it; 404 unknown version)."""
    return await _activate(bench, manager, store, events,
                           lambda apply: CompensationVersions(store).rollback(version, apply=apply), who,
                           "compensation.rollback")


@router.post("/from-model", response_class=PlainTextResponse,
             responses={**TOML_ANSWER, **errors(401, 403, 409, 422)})
async def compensation_from_model(bench: Bench, manager: Manager, store: Store, events: Events,
                                  who: Annotated[Principal, Depends(require("compensation.edit"))]
                                  ) -> PlainTextResponse:
    """The bench model's measuring-chain effects (scale, torsion) added to the compensator in use, kept as a new
    compensation version (an explicit step; the effects that cannot be compensator terms stay in the bench
    model and are named in the version's note). 422 when the bench model has none; 409 during a test."""
    moved: list[FromModel] = []

    def change(apply: Apply) -> StoredVersion:
        moved.append(CompensationVersions(store).from_model(bench.compensator_toml(), apply=apply))
        return moved[0].compensation

    answer = await _activate(bench, manager, store, events, change, who, "compensation.from_model")
    done = moved[0].bench_model
    events.publish("bench_model", version=done.version)
    audit(store, who, "bench_model.move", target="bench model", before=f"v{done.version - 1}",
          after=f"v{done.version}", detail=done.note)
    return answer

"""Saved test plans (recipes): named, versioned bodies of ``POST /api/tests``; an operator starts one for a unit
with ``POST /api/tests/from-plan`` (its serial number and customer), through the same path as a free request."""

from __future__ import annotations

import asyncio
from typing import Annotated, Any

from fastapi import APIRouter, Depends, Query
from fastapi import Path as PathParam
from pydantic import ValidationError

from tcms_daq.service.auth import Principal, require
from tcms_daq.service.deps import Bench, Manager, Store, errors
from tcms_daq.service.routes.tests import start_test
from tcms_daq.service.runner import RequestRejected
from tcms_daq.service.schemas import (
    PlanBody,
    PlanStart,
    PlanView,
    TestAccepted,
    TestDocumentation,
    TestRequest,
)
from tcms_daq.service.testruns import UnknownRun
from tcms_daq.service.users import audit
from tcms_daq.store.people import SavedPlan

router = APIRouter(prefix="/api/plans", tags=["plans"])
start_router = APIRouter(prefix="/api/tests", tags=["tests"])

PlanId = Annotated[int, PathParam(ge=1, le=2**31 - 1)]
#: what each start of a plan gives for its unit; a plan keeps none of them
PER_UNIT_FIELDS = ("serial_number", "operator", *TestDocumentation.model_fields)


def _plan_request(plan: SavedPlan, start: PlanStart) -> TestRequest:
    """The plan's request with the unit's fields of ``start``; 422 (one line) when the result is not valid."""
    unit = start.model_dump(exclude_none=True, exclude={"plan_id"})
    body = {k: v for k, v in plan.request.items() if k not in PER_UNIT_FIELDS} | unit
    try:
        return TestRequest.model_validate(body)
    except ValidationError as exc:
        first = exc.errors()[0]
        raise RequestRejected(f"plan {plan.name} v{plan.version}: {'.'.join(map(str, first['loc']))}: "
                              f"{first['msg']}") from None


@router.post("", status_code=201, response_model=PlanView, responses=errors(401, 403, 413, 422))
async def save_plan(body: PlanBody, bench: Bench, store: Store,
                    who: Annotated[Principal, Depends(require("plan.edit"))]) -> dict[str, Any]:
    """Save the next version of a plan (an engineer's right). The request is checked against this bench's and
    the reducer's bounds as a test would be (422 with one line); per-unit fields (serial number, customer,
    order) are not kept."""
    await asyncio.to_thread(bench.plan, body.request)  # RequestRejected (422) when it cannot run here
    request = body.request.model_dump(exclude_none=True, exclude=set(PER_UNIT_FIELDS))
    before = store.plan_by_name(body.name)
    saved = store.add_plan(body.name, request, who.name, body.note)
    audit(store, who, "plan.save", target=body.name,
          before=None if before is None else f"v{before.version} sha256 {before.summary()['sha256'][:16]}",
          after=f"v{saved.version} sha256 {saved.summary()['sha256'][:16]}", detail=body.note or None)
    return saved.summary()


@router.get("", response_model=list[PlanView])
def list_plans(store: Store, all_versions: Annotated[bool, Query(description="every version, not only the "
                                                                             "latest of each name")] = False
               ) -> list[dict[str, Any]]:
    """Saved plans: the latest version of each, by name (``all_versions``: every version, newest first)."""
    return [p.summary() for p in store.plans(all_versions)]


@router.get("/{plan_id}", response_model=PlanView, responses=errors(404))
def get_plan(plan_id: PlanId, store: Store) -> dict[str, Any]:
    """One plan version."""
    plan = store.plan(plan_id)
    if plan is None:
        raise UnknownRun(f"no plan with id {plan_id}")
    return plan.summary()


@start_router.post("/from-plan", status_code=202, response_model=TestAccepted,
                   responses=errors(401, 403, 404, 409, 413, 422))
def start_plan(body: PlanStart, manager: Manager, store: Store,
               who: Annotated[Principal, Depends(require("test.start_plan"))]) -> TestAccepted:
    """Start a test from a saved plan version for one unit (an operator's right): the plan's request with the
    unit's serial number, customer and order, through the same path as ``POST /api/tests``. The run records the
    plan's name and version and the user. 404 unknown plan; 422 / 409 as a test."""
    plan = store.plan(body.plan_id)
    if plan is None:
        raise UnknownRun(f"no plan with id {body.plan_id}")
    return start_test(manager, store, who, _plan_request(plan, body), plan)

"""Typed FastAPI dependencies: what a route handler may ask for (the objects the lifespan put on app.state).

``Store``, ``Bench``, ``Manager``, ``Live``, ``Events``, ``Analyses`` and ``Settings`` are ``Annotated`` types,
so a handler states its collaborators in its signature; ``StoredRunDep`` resolves ``{run_id}`` (404 unknown);
``RunWithSamplesDep`` also answers 410 when a retention policy retired its samples;
``AUTH`` is the bearer-token check of mutating operations. ``errors(...)`` documents a route's error answers.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Annotated, Any

from fastapi import Depends, Request

from tcms_daq.service.auth import require_token
from tcms_daq.service.discrepancy_runs import DiscrepancyRuns
from tcms_daq.service.events import EventHub
from tcms_daq.service.live import LiveHub
from tcms_daq.service.runner import Runner
from tcms_daq.service.schemas import ErrorBody, ValidationErrorBody
from tcms_daq.service.settings import ServiceSettings
from tcms_daq.service.te_discrepancy import TeAnalyses
from tcms_daq.service.testruns import TestManager, UnknownRun
from tcms_daq.store import Store as RunStoreType
from tcms_daq.store import StoredRun


def _state(name: str) -> Callable[[Request], Any]:
    """A dependency that hands out the collaborator the app keeps as ``app.state.<name>``."""

    def get(request: Request) -> Any:
        return getattr(request.app.state, name)

    get.__name__ = f"_{name}"
    return get


Store = Annotated[RunStoreType, Depends(_state("store"))]
Bench = Annotated[Runner, Depends(_state("runner"))]
Manager = Annotated[TestManager, Depends(_state("manager"))]
Live = Annotated[LiveHub, Depends(_state("live"))]
Events = Annotated[EventHub, Depends(_state("events"))]
Analyses = Annotated[DiscrepancyRuns, Depends(_state("discrepancy"))]
TeAnalysesDep = Annotated[TeAnalyses, Depends(_state("te_discrepancy"))]
Settings = Annotated[ServiceSettings, Depends(_state("settings"))]


def _stored_run(run_id: str, store: Store) -> StoredRun:
    record = store.get_run(run_id)
    if record is None:
        raise UnknownRun(f"no test with id {run_id!r}")
    return record


StoredRunDep = Annotated[StoredRun, Depends(_stored_run)]


def _run_with_samples(run: StoredRunDep) -> StoredRun:
    run.require_samples()  # SamplesRetired: 410 Gone, before a streamed answer has begun
    return run


RunWithSamplesDep = Annotated[StoredRun, Depends(_run_with_samples)]
AUTH = [Depends(require_token)]

_ERRORS: dict[int, dict[str, Any]] = {
    401: {"model": ErrorBody, "description": "missing or invalid bearer token"},
    403: {"model": ErrorBody, "description": "the role lacks the right: names the role needed"},
    404: {"model": ErrorBody, "description": "no such test, version or analysis"},
    409: {"model": ErrorBody, "description": "a test is running (or another analysis)"},
    410: {"model": ErrorBody, "description": "the run's samples were retired by the store's retention policy"},
    413: {"model": ErrorBody, "description": "request body above the service's limit"},
    422: {"model": ValidationErrorBody, "description": "invalid request: one line naming the field"},
    501: {"model": ErrorBody, "description": "an optional part this installation lacks (names the extra to install)"},
}


def errors(*codes: int) -> dict[int | str, dict[str, Any]]:
    """The documented error answers of a route (``responses=errors(404, 422)``)."""
    return {code: _ERRORS[code] for code in codes}

"""Discrepancy analyses of stored runs for the API (``POST /api/discrepancy``, DESIGN §7–§8) and the bench model
they add to (``POST /api/discrepancy/{id}/apply``, ``GET /api/model``).

The work is :class:`tcms_daq.store.discrepancy.AnalysisArchive`'s, shared with ``tcms discrepancy --run ID``:
the stored run against the bench model in use (the catalogue reducer re-simulated on the run's torque, plus
the effects accepted so far), kept under ``<data dir>/discrepancy/<id>/``. This module adds what the service
needs around it: one analysis at a time, the HTTP error types and the events.

:meth:`DiscrepancyRuns.analyse` is blocking (CPU-bound, about a second for a 10 000-sample run): the app calls
it in a worker thread.
"""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Any

from tcms_daq.errors import TcmsError
from tcms_daq.service.events import EventHub
from tcms_daq.service.runner import RequestRejected
from tcms_daq.service.schemas import DiscrepancyRequest
from tcms_daq.service.testruns import Conflict, UnknownRun
from tcms_daq.store import ACTIVE_STATUSES, Store
from tcms_daq.store.discrepancy import (
    AnalysisArchive,
    ProvisionalNames,
    StaleAnalysis,
    UnknownAnalysis,
    bench_model,
)


class DiscrepancyRuns:
    """Runs and keeps discrepancy analyses of the runs in ``store``; files under ``root``."""

    def __init__(self, store: Store, root: Path, events: EventHub | None = None):
        self.store = store
        self.archive = AnalysisArchive(root)
        self.events = events
        self._busy = threading.Lock()

    def analyse(self, request: DiscrepancyRequest) -> dict[str, Any]:
        """Analyse one stored run; returns the stored result document.

        UnknownRun (404) for an unknown run, Conflict (409) for a run still active or while another analysis
        runs, RequestRejected (422, one line) for a run that cannot be compared (too few samples, no reducer,
        no torque–angle curve …).
        """
        from tcms_daq.sim.physics import catalogue_model

        record = self.store.get_run(request.run_id)
        if record is None:
            raise UnknownRun(f"no test with id {request.run_id!r}")
        if record.status in ACTIVE_STATUSES:
            raise Conflict(f"test {record.id} is {record.status}; analyse it after it ends")
        if not self._busy.acquire(blocking=False):
            raise Conflict("another discrepancy analysis is running; try again when it has finished")
        try:
            doc = self.archive.analyse(self.store, request.run_id, catalogue_model,
                                       signal_period_arcsec=request.signal_period_arcsec, effects=request.effects)
        except TcmsError as exc:
            raise RequestRejected(str(exc)) from None
        finally:
            self._busy.release()
        if self.events is not None:
            self.events.publish("discrepancy", id=doc["id"], run_id=doc["run_id"], verdict=doc["verdict"],
                                effects=[e["name"] for e in doc["effects"]])
        return doc

    def apply(self, analysis_id: str, accept_provisional: bool = False) -> dict[str, Any]:
        """Add an analysis's effects to the bench model; the new version's view (as :meth:`model`).
        404 unknown analysis, 409 stale (made against an older version) or provisional names not accepted,
        422 nothing named."""
        try:
            added = self.archive.apply(self.store, analysis_id, accept_provisional=accept_provisional)
        except UnknownAnalysis as exc:
            raise UnknownRun(str(exc)) from None
        except (StaleAnalysis, ProvisionalNames) as exc:
            raise Conflict(str(exc)) from None
        except TcmsError as exc:
            raise RequestRejected(str(exc)) from None
        if self.events is not None:
            self.events.publish("bench_model", version=added.version, analysis_id=analysis_id)
        return self.model()

    def model(self) -> dict[str, Any]:
        """The bench model in use: its version, its accepted effects and its history (newest first)."""
        version, model = bench_model(self.store)
        return {"version": version,
                "terms": [{"standard_uncertainty": {}, **t.to_dict()} for t in model.terms],
                "toml": model.to_toml() if version else None,
                "history": [v.summary() for v in self.store.bench_model_history()]}

    # -- stored analyses -------------------------------------------------------------------------------------
    def path(self, analysis_id: str, filename: str) -> Path:
        try:
            return self.archive.path(analysis_id, filename)
        except UnknownAnalysis as exc:
            raise UnknownRun(str(exc)) from None

    def get(self, analysis_id: str) -> dict[str, Any]:
        try:
            return self.archive.get(analysis_id)
        except UnknownAnalysis as exc:
            raise UnknownRun(str(exc)) from None

    def list(self, limit: int = 100) -> list[dict[str, Any]]:
        return self.archive.list(limit)

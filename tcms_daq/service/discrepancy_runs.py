"""Discrepancy analyses of stored runs for the API (``POST /api/discrepancy``, DESIGN §7–§8).

The same work as ``tcms discrepancy --run ID``: the stored run's measured angle against the bench model
re-simulated on its own torque trace (:func:`tcms_daq.store.discrepancy.pair_from_store`), through
:func:`tcms_daq.discrepancy.workflow.run_discrepancy`. Each analysis is kept under
``<data dir>/discrepancy/<id>/`` with the files of ``tcms discrepancy --out`` (``report.html``, ``model.toml``,
``resimulated.csv``) and ``result.json`` (the ``--json`` object plus ``id``, ``run_id``, ``created_at`` and
the options), written last, so a directory without it is an analysis that did not finish.

:meth:`DiscrepancyRuns.analyse` is blocking (CPU-bound, about a second for a 10 000-sample run): the app calls
it in a worker thread, one analysis at a time.
"""

from __future__ import annotations

import json
import re
import threading
import time
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from tcms_daq.errors import TcmsError
from tcms_daq.service.events import EventHub
from tcms_daq.service.runner import RequestRejected
from tcms_daq.service.schemas import DiscrepancyRequest
from tcms_daq.service.testruns import Conflict, UnknownRun
from tcms_daq.store import ACTIVE_STATUSES, RunStore, new_run_id

RESULT_FILENAME = "result.json"
_ID_PATTERN = re.compile(r"^\d{8}-\d{6}-[0-9a-f]{6}$")  # new_run_id(); also keeps ids out of other paths


class DiscrepancyRuns:
    """Runs and keeps discrepancy analyses of the runs in ``store``; files under ``root``."""

    def __init__(self, store: RunStore, root: Path, events: EventHub | None = None):
        self.store = store
        self.root = Path(root)
        self.events = events
        self._busy = threading.Lock()

    def analyse(self, request: DiscrepancyRequest) -> dict[str, Any]:
        """Analyse one stored run; returns the stored result document.

        UnknownRun (404) for an unknown run, Conflict (409) for a run still active or while another analysis
        runs, RequestRejected (422, one line) for a run that cannot be compared (too few samples, no reducer,
        no torque–angle curve …).
        """
        record = self.store.get_run(request.run_id)
        if record is None:
            raise UnknownRun(f"no test with id {request.run_id!r}")
        if record.status in ACTIVE_STATUSES:
            raise Conflict(f"test {record.id} is {record.status}; analyse it after it ends")
        if not self._busy.acquire(blocking=False):
            raise Conflict("another discrepancy analysis is running; try again when it has finished")
        try:
            return self._analyse(request)
        finally:
            self._busy.release()

    def _analyse(self, request: DiscrepancyRequest) -> dict[str, Any]:
        from sim.physics import catalogue_model
        from tcms_daq.analysis.evaluation import jsonable
        from tcms_daq.discrepancy.workflow import run_discrepancy
        from tcms_daq.store.discrepancy import pair_from_store, write_outputs

        run_id = request.run_id
        try:
            measured, simulated = pair_from_store(self.store, run_id, catalogue_model)
        except TcmsError as exc:
            raise RequestRejected(str(exc)) from None
        try:
            result = run_discrepancy(measured, simulated, signal_period_arcsec=request.signal_period_arcsec,
                                     has_time=True, effects=request.effects)
        except (TcmsError, ValueError, np.linalg.LinAlgError) as exc:
            raise RequestRejected(f"run {run_id!r} cannot be compared with the model: {exc}") from None
        analysis_id = new_run_id()
        out = self.root / analysis_id
        write_outputs(result, measured, simulated, out, f"Discrepancy report: stored run {run_id}")
        doc = {
            "id": analysis_id,
            "run_id": run_id,
            "created_at": datetime.fromtimestamp(time.time(), UTC).isoformat(timespec="milliseconds"),
            "options": request.model_dump(exclude={"run_id"}),
            "report_url": f"/api/discrepancy/{analysis_id}/report",
            **jsonable(result.to_dict()),
        }
        tmp = out / (RESULT_FILENAME + ".tmp")
        tmp.write_text(json.dumps(doc, indent=1), encoding="utf-8")
        tmp.replace(out / RESULT_FILENAME)
        if self.events is not None:
            self.events.publish("discrepancy", id=analysis_id, run_id=run_id,
                                effects=[e["name"] for e in doc["effects"]])
        return doc

    # -- stored analyses -------------------------------------------------------------------------------------
    def path(self, analysis_id: str, filename: str) -> Path:
        """A file of a finished analysis; UnknownRun (404) when there is no such analysis."""
        folder = self.root / analysis_id
        if not _ID_PATTERN.match(analysis_id) or not (folder / RESULT_FILENAME).is_file():
            raise UnknownRun(f"no discrepancy analysis with id {analysis_id!r}")
        return folder / filename

    def get(self, analysis_id: str) -> dict[str, Any]:
        return json.loads(self.path(analysis_id, RESULT_FILENAME).read_text(encoding="utf-8"))

    def list(self, limit: int = 100) -> list[dict[str, Any]]:
        """Finished analyses, newest first: id, run_id, created_at, named effects, held-out RMS before/after."""
        if not self.root.is_dir():
            return []
        ids = sorted((p.name for p in self.root.iterdir() if _ID_PATTERN.match(p.name)
                      and (p / RESULT_FILENAME).is_file()), reverse=True)
        out = []
        for analysis_id in ids[:limit]:
            doc = self.get(analysis_id)
            out.append({k: doc.get(k) for k in ("id", "run_id", "created_at", "report_url",
                                                "cv_rms_before_arcsec", "cv_rms_after_arcsec")}
                       | {"effects": [e["name"] for e in doc.get("effects", [])]})
        return out

"""The discrepancy workflow on the transmission error over the service (issue 28): a stored transmission-error run
against the unit's TE model (``tcms_daq.transmission.te_model``), the lines the model lacks named by their order and
component (or by their order alone), and the model's next version when they are applied. The versions are kept in
the run store beside the bench model's (``te_models``: the whole ``tcms-te-model/1`` TOML of each version, with the
analysis and the run it came from), one history per bench, each version the model of one reducer type.

Version 0 of a reducer's model, before anything was applied, is the catalogue's harmonics of the type
(``[reducers.<NAME>.sim.transmission] harmonics``, its orders from the kinematics), or none.

``POST /api/te-discrepancy`` analyses (blocking, about a second: the app calls it in a worker thread), ``POST
/api/te-discrepancy/{id}/apply`` adds the named lines as the next version (409 when the analysis was made against
an older version), ``GET /api/te-model?reducer=`` the model in use and its history. Analyses are kept as JSON under
``<data dir>/te-discrepancy/``.
"""

from __future__ import annotations

import json
import math
import threading
from collections.abc import Mapping
from pathlib import Path
from typing import Any, cast

from tcms_daq.config.models import BenchConfig, ReducerSpec
from tcms_daq.errors import TcmsError
from tcms_daq.service.events import EventHub
from tcms_daq.service.runner import RequestRejected
from tcms_daq.service.testruns import Conflict, UnknownRun
from tcms_daq.store import ACTIVE_STATUSES, Store, new_run_id
from tcms_daq.store.base import TeModels
from tcms_daq.transmission.kinematics import component_orders_per_output_rev
from tcms_daq.transmission.te_model import TeHarmonicTerm, TeModel, apply_findings, compare_te, parse_te_model

DIRNAME = "te-discrepancy"


def catalogue_te_model(spec: ReducerSpec) -> TeModel:
    """Version 0 of a reducer type's TE model: the catalogue's harmonics (none without them)."""
    sim = spec.sim.transmission if spec.sim is not None else None
    if sim is None or spec.kinematics is None:
        return TeModel(float(spec.ratio or 1.0), (), spec.name, version=0)
    orders = component_orders_per_output_rev(spec.kinematics.teeth(spec.kind))
    terms = tuple(TeHarmonicTerm(h.harmonic * orders[h.component], h.amplitude_arcsec, h.phase_deg,
                                 h.component if h.harmonic == 1 else f"{h.component} {h.harmonic}×", "catalogue")
                  for h in sim.harmonics)
    return TeModel(float(spec.ratio or 1.0), terms, spec.name, version=0)


class TeAnalyses:
    """TE discrepancy analyses of the runs in ``store`` (module docstring); ``reducers`` the catalogue, ``config``
    the bench config (its ``[uncertainty.station]`` holds what the measuring chain alone can make)."""

    def __init__(self, store: Store, root: Path, reducers: Mapping[str, ReducerSpec], config: BenchConfig | None,
                 events: EventHub | None = None):
        self.store = store
        self.models = cast(TeModels, store)
        self.root = root
        self.reducers = dict(reducers)
        self.config = config
        self.events = events
        self._busy = threading.Lock()

    def _spec(self, name: str) -> ReducerSpec:
        spec = self.reducers.get(name) or {k.casefold(): v for k, v in self.reducers.items()}.get(name.casefold())
        if spec is None:
            raise RequestRejected(f"unknown reducer {name!r} (known: {', '.join(self.reducers)})")
        return spec

    def model_for(self, reducer: str) -> tuple[int, TeModel]:
        """(stored version, model) of the reducer type's TE model in use (version 0: the catalogue's)."""
        spec = self._spec(reducer)
        for row in self.models.te_model_history(1000):
            found = self.models.te_model(row.version)
            if found is not None:
                model = parse_te_model(found[1], f"TE model version {row.version}")
                if (model.reducer or "").casefold() == spec.name.casefold():
                    return row.version, model
        return 0, catalogue_te_model(spec)

    # -- analyse and apply -----------------------------------------------------------------------------------
    def analyse(self, run_id: str) -> dict[str, Any]:
        """Compare a stored transmission-error run with its unit's model; the stored analysis document.
        UnknownRun (404), Conflict (409: the run is active, another analysis runs), RequestRejected (422: not a
        completed transmission-error run, or its record cannot be compared)."""
        from tcms_daq.uncertainty.station import te_allowance

        record = self.store.get_run(run_id)
        if record is None:
            raise UnknownRun(f"no test with id {run_id!r}")
        if record.status in ACTIVE_STATUSES:
            raise Conflict(f"test {record.id} is {record.status}; analyse it after it ends")
        results = record.results or {}
        if results.get("method") != "transmission-error" or record.status != "completed":
            raise RequestRejected(f"test {record.id} is not a completed transmission-error test "
                                  f"(method {results.get('method') or (record.request or {}).get('method') or 'stiffness'}"
                                  f", {record.status})")
        record.require_samples()
        if not self._busy.acquire(blocking=False):
            raise Conflict("another TE discrepancy analysis is running; try again when it has finished")
        try:
            reducer = str((record.request or {}).get("reducer") or results.get("reducer"))
            spec = self._spec(reducer)
            version, model = self.model_for(spec.name)
            cols = self.store.read_columns(run_id)
            t, a_in, a_out = cols.get("time_s"), cols.get("input_angle_arcsec"), cols.get("angle_arcsec")
            if t is None or a_in is None or a_out is None:
                raise RequestRejected(f"test {run_id} has no input angle channel to compare")
            chain = self.config.uncertainty.station if self.config is not None else None
            teeth = spec.kinematics.teeth(spec.kind) if spec.kinematics is not None else None
            allowance = te_allowance(t, a_in, a_out, ratio=model.ratio, chain=chain)
            comparison = compare_te(t, a_in, a_out, model, teeth=teeth, allowance=allowance)
        except TcmsError as exc:
            raise RequestRejected(str(exc)) from None
        finally:
            self._busy.release()
        analysis_id = new_run_id()
        proposed = apply_findings(model, comparison, source=f"te discrepancy {analysis_id} of run {run_id}")
        found = comparison.to_dict()
        found.pop("per_direction", None)
        doc = {"id": analysis_id, "run_id": run_id, "reducer": spec.name, "against_version": version,
               **found, "proposed_toml": proposed.to_toml() if comparison.named else None}
        self.root.mkdir(parents=True, exist_ok=True)
        (self.root / f"{analysis_id}.json").write_text(json.dumps(doc, allow_nan=False), encoding="utf-8")
        if self.events is not None:
            self.events.publish("te_discrepancy", id=analysis_id, run_id=run_id, verdict=doc["verdict"],
                                named_orders=doc["named_orders"], unexplained_orders=doc["unexplained_orders"])
        return doc

    def get(self, analysis_id: str) -> dict[str, Any]:
        path = self.root / f"{analysis_id}.json"
        if not analysis_id.replace("-", "").isalnum() or not path.is_file():
            raise UnknownRun(f"no TE discrepancy analysis with id {analysis_id!r}")
        doc: dict[str, Any] = json.loads(path.read_text(encoding="utf-8"))
        return doc

    def apply(self, analysis_id: str) -> dict[str, Any]:
        """Add an analysis's named lines to its reducer's model as the next version; the model's view.
        404 unknown analysis, 409 made against an older version, 422 nothing named."""
        doc = self.get(analysis_id)
        version, _ = self.model_for(doc["reducer"])
        if version != doc["against_version"]:
            raise Conflict(f"TE discrepancy {analysis_id} was made against version {doc['against_version']} of the "
                           f"{doc['reducer']} TE model; it is at version {version} now: analyse the run again")
        if not doc.get("proposed_toml"):
            raise RequestRejected(f"TE discrepancy {analysis_id} named nothing to add ({doc['verdict']})")
        added = self.models.add_te_model(doc["proposed_toml"], note=doc.get("verdict_words", "")[:500],
                                         analysis_id=analysis_id, run_id=doc["run_id"])
        if self.events is not None:
            self.events.publish("te_model", version=added.version, reducer=doc["reducer"], analysis_id=analysis_id)
        return self.model(doc["reducer"])

    def model(self, reducer: str) -> dict[str, Any]:
        """The reducer type's TE model in use, its harmonics and the store's TE model history (newest first)."""
        version, model = self.model_for(reducer)
        return {"reducer": model.reducer or reducer, "version": version, "ratio": model.ratio,
                "harmonics": [h.to_dict() for h in model.harmonics],
                "toml": model.to_toml(), "history": [v.summary() for v in self.models.te_model_history()]}


def order_words(orders: list[float]) -> str:
    """'27.3, 78' (for messages)."""
    return ", ".join(f"{k:.4g}" for k in orders if math.isfinite(k))

"""The discrepancy workflow's inputs and outputs on disk: the (measured, re-simulated) pair of a stored run and
the report folder of an analysis (``report.html``, ``model.toml``, ``resimulated.csv``). Used by the CLI and the
service; the forward model comes from the caller (``sim.physics.catalogue_model`` on both today)."""

from __future__ import annotations

import json
import math
import re
import time
from collections.abc import Callable
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from tcms_daq.discrepancy.model_file import (
    DiscrepancyModel,
    apply_model,
    model_from_result,
    parse_model,
    resimulated_samples,
)
from tcms_daq.discrepancy.report import render_html
from tcms_daq.discrepancy.stored import ForwardModel, compared_rows, resimulate
from tcms_daq.discrepancy.workflow import DiscrepancyResult
from tcms_daq.errors import DataFormatError, TcmsError
from tcms_daq.samples import Samples, write_csv
from tcms_daq.store.base import BenchModelVersion, Store, StoredRun, new_run_id

ModelForReducer = Callable[[str], ForwardModel]
"""Reducer name → its forward model; raises DataFormatError (one line) for an unknown reducer."""


def recorded_reducer(record: StoredRun) -> str | None:
    """The reducer a run was made on: from its request, else from the [sim] table of its config snapshot."""
    req = record.request or {}
    for key in ("reducer", "reducer_name"):
        if isinstance(req.get(key), str):
            return req[key]
    snap = record.config_snapshot or {}
    sim = snap.get("sim") if isinstance(snap, dict) else None
    if isinstance(sim, dict) and isinstance(sim.get("reducer"), str):
        return sim["reducer"]
    return None


class StaleAnalysis(TcmsError):
    """An analysis made against an older bench model version cannot be applied to the current one."""


def bench_model(store: Store) -> tuple[int, DiscrepancyModel]:
    """(version, model) of the bench model in use: the effects accepted so far (version 0: none)."""
    latest = store.bench_model()
    if latest is None:
        return 0, DiscrepancyModel()
    return latest[0].version, parse_model(latest[1], f"bench model version {latest[0].version}")


def apply_analysis(store: Store, found: DiscrepancyModel, *, against_version: int, analysis_id: str,
                   run_id: str, note: str = "") -> BenchModelVersion:
    """Add the terms an analysis found to the bench model as its next version. The analysis must have been made
    against the version in use (StaleAnalysis otherwise: its terms are what *that* version missed)."""
    version, model = bench_model(store)
    if version != against_version:
        raise StaleAnalysis(f"analysis {analysis_id} was made against bench model version {against_version}; "
                            f"the bench model is now version {version}: analyse the run again")
    if not found.terms:
        raise DataFormatError(f"analysis {analysis_id} named no effect: nothing to add to the bench model")
    new = model.with_terms_of(DiscrepancyModel(0.0, model.signal_period_arcsec, found.terms, found.fit_range,
                                               found.drift_reference_time_s))
    names = ", ".join(t.name for t in found.terms)
    return store.add_bench_model(new.to_toml(), note or f"added {names} from analysis {analysis_id} of run {run_id}",
                                 analysis_id=analysis_id, run_id=run_id)


def pair_from_store(store: Store, run_id: str, model_for: ModelForReducer, where: str = "",
                    effects_model: DiscrepancyModel | None = None) -> tuple[Samples, Samples]:
    """(measured, simulated) of run ``run_id`` of an open store: the simulation is the recorded reducer's model
    on the measured torque, with the terms of ``effects_model`` (the bench model's accepted effects) added.
    Raises DataFormatError (one line) for an unknown run, too few samples or no recorded reducer."""
    record = store.get_run(run_id)
    if record is None:
        raise DataFormatError(f"unknown run {run_id!r}{where}")
    measured = store.read_samples(run_id)
    if len(measured) < 12:
        raise DataFormatError(f"run {run_id!r} has {len(measured)} samples: too few to compare")
    name = recorded_reducer(record)
    if name is None:
        raise DataFormatError(f"run {run_id!r} does not record its reducer: cannot re-simulate it")
    measured = Samples(measured.time_s, measured.torque_nm, measured.angle_arcsec)
    terms = (DiscrepancyModel(0.0, effects_model.signal_period_arcsec, effects_model.terms)
             if effects_model is not None and effects_model.terms else None)

    def with_terms(run: Samples) -> Samples:
        return apply_model(terms, run) if terms is not None else run

    # the whole run, so the model's loop state is its own; its initial state fitted against the model in use
    simulated = resimulate(measured, model_for(name), with_terms if terms is not None else None)
    # compared from the first reversal (the state before is unknown) to the programme's end (the loader disabled)
    rows = compared_rows(measured.time_s, measured.torque_nm, programme_end_s(record))
    measured, simulated = measured.select(rows), simulated.select(rows)
    return measured, with_terms(simulated)


def programme_end_s(record: StoredRun) -> float | None:
    """Where a stored run's programme ended (clock s): the end of its last loop in its results (the evaluation's
    loop times; the final ramp to zero and the loader's disabling come after it), None when it has none."""
    loops = (record.results or {}).get("loops")
    ends = [float(lp["end_time_s"]) for lp in loops if isinstance(lp, dict)
            and isinstance(lp.get("end_time_s"), int | float) and not isinstance(lp.get("end_time_s"), bool)
            and math.isfinite(lp["end_time_s"])] if isinstance(loops, list) else []
    return max(ends) if ends else None


def suggested_runs(result: DiscrepancyResult, record: StoredRun | None, measured: Samples) -> list[dict[str, Any]]:
    """For each alias group a test request can separate: ``{"names", "kind", "why", "request"}`` with the
    ``POST /api/tests`` body of that run (the stored run's reducer, torque and documentation; its rate from the
    request, else the bench's [procedure], else a quarter of the torque per second as the plan's default)."""
    import numpy as np

    from tcms_daq.discrepancy.stored import separating_request

    if record is None:
        return []
    request = dict(record.request or {})
    snapshot: dict[str, Any] = record.config_snapshot if isinstance(record.config_snapshot, dict) else {}

    def section(name: str) -> dict[str, Any]:
        value = snapshot.get(name)
        return value if isinstance(value, dict) else {}

    procedure, bench = section("procedure"), section("bench")
    reducer = recorded_reducer(record)
    torque = request.get("max_torque_nm") or procedure.get("max_torque_nm")
    if torque is None and len(measured):
        torque = round(float(np.max(np.abs(measured.torque_nm))))
    if reducer is None or not torque:
        return []
    rates = request.get("rates") or []
    rate = request.get("rate_nm_per_s") or (rates[0] if rates else None) or procedure.get("rate_nm_per_s") \
        or float(torque) / 4.0
    max_rate = bench.get("max_rate_nm_per_s") or bench.get("max_torque_nm") or float(torque)
    out: list[dict[str, Any]] = []
    for alias in result.aliases:
        kind = alias.separating_run
        body = separating_request(kind, request, reducer=reducer, max_torque_nm=float(torque),
                                  rate_nm_per_s=float(rate), max_rate_nm_per_s=float(max_rate)) if kind else None
        if body is not None and all(o["request"] != body for o in out):
            out.append({"names": list(alias.names), "kind": kind, "why": alias.separating_experiment,
                        "request": body})
    return out


def write_outputs(result: DiscrepancyResult, measured: Samples, simulated: Samples, out_dir: str | Path,
                  title: str) -> list[Path]:
    """Write ``report.html``, ``model.toml`` and ``resimulated.csv`` of an analysis into ``out_dir``."""
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise DataFormatError(f"{out}: cannot create the output directory ({exc})") from None
    paths = [out / "report.html", out / "model.toml", out / "resimulated.csv"]
    paths[0].write_text(render_html(result, title=title), encoding="utf-8")
    model_from_result(result).save(paths[1])
    if result.paired is not None:  # the rows the analysis used (the simulation put onto the measured rows)
        measured, simulated = result.paired
    write_csv(paths[2], resimulated_samples(result, simulated, measured))
    return paths


# -- the archive of analyses: <data dir>/discrepancy/<id>/ ------------------------------------------------------

ANALYSES_DIRNAME = "discrepancy"
RESULT_FILENAME = "result.json"
_ANALYSIS_ID = re.compile(r"^\d{8}-\d{6}-[0-9a-f]{6}$")  # new_run_id(); also keeps ids out of other paths


class UnknownAnalysis(TcmsError):
    """No finished analysis with that id."""


class AnalysisArchive:
    """Discrepancy analyses of stored runs, each in ``root/<id>/``: the files of ``tcms discrepancy --out``
    (``report.html``, ``model.toml``, ``resimulated.csv``) and ``result.json`` (the ``--json`` object plus
    ``id``, ``run_id``, ``created_at``, the options and the bench model version it was made against), written
    last, so a folder without it is an analysis that did not finish. Shared by the CLI and the service."""

    def __init__(self, root: str | Path):
        self.root = Path(root)

    def analyse(self, store: Store, run_id: str, model_for: ModelForReducer, *,
                signal_period_arcsec: float = 72.0, effects: list[str] | None = None) -> dict[str, Any]:
        """Analyse stored run ``run_id`` against the bench model in use and keep it; returns the document.
        DataFormatError (one line) when the run cannot be compared."""
        import numpy as np

        from tcms_daq.analysis.evaluation import jsonable
        from tcms_daq.discrepancy.workflow import run_discrepancy

        version, model = bench_model(store)
        measured, simulated = pair_from_store(store, run_id, model_for, effects_model=model)
        try:
            result = run_discrepancy(measured, simulated, signal_period_arcsec=signal_period_arcsec,
                                     has_time=True, effects=effects)
        except (ValueError, np.linalg.LinAlgError) as exc:
            raise DataFormatError(f"run {run_id!r} cannot be compared with the model: {exc}") from None
        analysis_id = new_run_id()
        out = self.root / analysis_id
        write_outputs(result, measured, simulated, out,
                      f"Discrepancy report: stored run {run_id} against bench model version {version}")
        doc = {
            "id": analysis_id,
            "run_id": run_id,
            "created_at": datetime.fromtimestamp(time.time(), UTC).isoformat(timespec="milliseconds"),
            "options": {"signal_period_arcsec": signal_period_arcsec, "effects": effects},
            "report_url": f"/api/discrepancy/{analysis_id}/report",
            "model_version": version,
            **jsonable(result.to_dict()),
            "suggested_runs": suggested_runs(result, store.get_run(run_id), measured),
        }
        tmp = out / (RESULT_FILENAME + ".tmp")
        tmp.write_text(json.dumps(doc, indent=1), encoding="utf-8")
        tmp.replace(out / RESULT_FILENAME)
        return doc

    def apply(self, store: Store, analysis_id: str, *, accept_provisional: bool = False) -> BenchModelVersion:
        """Add the effects analysis ``analysis_id`` named to the bench model (its next version). Provisional
        names (the verdict was not ``explained``) only with ``accept_provisional``."""
        doc = self.get(analysis_id)
        if not doc.get("effects") and not any(a.get("in_model") for a in doc.get("aliases", [])):
            raise DataFormatError(f"analysis {analysis_id} named no effect: nothing to add to the bench model")
        if doc.get("names_provisional") and not accept_provisional:
            raise ProvisionalNames(
                f"analysis {analysis_id} is {doc.get('verdict')}: its names are provisional; accept them "
                "explicitly (accept_provisional) or find what remains first")
        found = parse_model(self.path(analysis_id, "model.toml").read_text(encoding="utf-8"),
                            f"analysis {analysis_id} model.toml")
        return apply_analysis(store, found, against_version=int(doc.get("model_version", 0)),
                              analysis_id=analysis_id, run_id=str(doc["run_id"]))

    def path(self, analysis_id: str, filename: str) -> Path:
        """A file of a finished analysis; UnknownAnalysis when there is no such analysis."""
        folder = self.root / analysis_id
        if not _ANALYSIS_ID.match(analysis_id) or not (folder / RESULT_FILENAME).is_file():
            raise UnknownAnalysis(f"no discrepancy analysis with id {analysis_id!r}")
        return folder / filename

    def get(self, analysis_id: str) -> dict[str, Any]:
        return json.loads(self.path(analysis_id, RESULT_FILENAME).read_text(encoding="utf-8"))

    def list(self, limit: int = 100) -> list[dict[str, Any]]:
        """Finished analyses, newest first: id, run_id, created_at, verdict, named effects, held-out RMS."""
        if not self.root.is_dir():
            return []
        ids = sorted((p.name for p in self.root.iterdir() if _ANALYSIS_ID.match(p.name)
                      and (p / RESULT_FILENAME).is_file()), reverse=True)
        out = []
        for analysis_id in ids[:limit]:
            doc = self.get(analysis_id)
            out.append({k: doc.get(k) for k in ("id", "run_id", "created_at", "report_url", "verdict",
                                                "model_version", "cv_rms_before_arcsec", "cv_rms_after_arcsec")}
                       | {"effects": [e["name"] for e in doc.get("effects", [])]})
        return out


class ProvisionalNames(TcmsError):
    """The analysis's names are provisional (structure remained) and were not accepted explicitly."""

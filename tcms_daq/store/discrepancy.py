"""The discrepancy workflow's inputs and outputs on disk: the (measured, re-simulated) pair of a stored run and
the report folder of an analysis (``report.html``, ``model.toml``, ``resimulated.csv``). Used by the CLI and the
service; the forward model comes from the caller (``sim.physics.catalogue_model`` on both today)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from tcms_daq.discrepancy.model_file import model_from_result, resimulated_samples
from tcms_daq.discrepancy.report import render_html
from tcms_daq.discrepancy.stored import ForwardModel, resimulate
from tcms_daq.discrepancy.workflow import DiscrepancyResult
from tcms_daq.errors import DataFormatError
from tcms_daq.samples import Samples, write_csv
from tcms_daq.store.sqlite_store import STORE_FILENAME, RunStore, StoredRun

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


def pair_from_store(store: RunStore, run_id: str, model_for: ModelForReducer, where: str = ""
                    ) -> tuple[Samples, Samples]:
    """(measured, simulated) of run ``run_id`` of an open store: the simulation is the recorded reducer's model
    on the measured torque. Raises DataFormatError (one line) for an unknown run, too few samples or no recorded
    reducer."""
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
    return measured, resimulate(measured, model_for(name))


def stored_pair(run_id: str, data_dir: str | Path, model_for: ModelForReducer) -> tuple[Samples, Samples]:
    """(measured, simulated) of a run in the store under ``data_dir`` (opened read-only for recovery: a service
    may be running a test in it right now)."""
    path = Path(data_dir) / STORE_FILENAME
    if not path.exists():
        raise DataFormatError(f"no run store at {path} (give --data-dir)")
    store = RunStore(path, recover=False)
    try:
        return pair_from_store(store, run_id, model_for, where=f" in {path}")
    finally:
        store.close()


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

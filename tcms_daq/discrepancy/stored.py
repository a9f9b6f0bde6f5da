"""A stored run against the bench model re-simulated on its own torque trace (``tcms discrepancy --run ID``)."""

from __future__ import annotations

import os
from pathlib import Path

from tcms_daq.errors import DataFormatError
from tcms_daq.samples import Samples


def _reducer_name(record) -> str | None:
    req = record.request or {}
    for key in ("reducer", "reducer_name"):
        if isinstance(req.get(key), str):
            return req[key]
    snap = record.config_snapshot or {}
    sim = snap.get("sim") if isinstance(snap, dict) else None
    if isinstance(sim, dict) and isinstance(sim.get("reducer"), str):
        return sim["reducer"]
    return None


def resimulate(measured: Samples, reducer_name: str) -> Samples:
    """The catalogue reducer's forward model (``sim.physics.twist_arcsec``) on the measured torque trace."""
    from sim.physics import physics_from_spec, twist_arcsec
    from tcms_daq.config import load_reducer_catalogue

    catalogue = load_reducer_catalogue()
    if reducer_name not in catalogue:
        raise DataFormatError(f"reducer {reducer_name!r} is not in the reducer catalogue")
    angle, _ = twist_arcsec(measured.torque_nm, physics_from_spec(catalogue[reducer_name]))
    return Samples(measured.time_s, measured.torque_nm, angle)


def stored_pair(run_id: str, data_dir: str | Path | None = None) -> tuple[Samples, Samples]:
    """(measured, simulated) of a stored run; raises DataFormatError for an unknown or empty run."""
    from tcms_daq.service.app import STORE_FILENAME
    from tcms_daq.store import RunStore

    base = Path(data_dir or os.environ.get("TCMS_DATA_DIR", "data"))
    path = base / STORE_FILENAME
    if not path.exists():
        raise DataFormatError(f"no run store at {path} (give --data-dir)")
    store = RunStore(path, recover=False)  # a service may be running a test in this store right now
    try:
        return pair_from_store(store, run_id, where=f" in {path}")
    finally:
        store.close()


def pair_from_store(store, run_id: str, where: str = "") -> tuple[Samples, Samples]:
    """(measured, simulated) of run ``run_id`` of an open :class:`~tcms_daq.store.RunStore` (CLI and API).

    Raises DataFormatError (one line) for an unknown run, too few samples or no recorded reducer.
    """
    record = store.get_run(run_id)
    if record is None:
        raise DataFormatError(f"unknown run {run_id!r}{where}")
    measured = store.read_samples(run_id)
    if len(measured) < 12:
        raise DataFormatError(f"run {run_id!r} has {len(measured)} samples: too few to compare")
    name = _reducer_name(record)
    if name is None:
        raise DataFormatError(f"run {run_id!r} does not record its reducer: cannot re-simulate it")
    measured = Samples(measured.time_s, measured.torque_nm, measured.angle_arcsec)
    return measured, resimulate(measured, name)

"""A stored run against the bench model re-simulated on its own torque trace (``tcms discrepancy --run ID``)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from scipy.signal import savgol_filter

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


TORQUE_SMOOTHING_S = 0.05


def applied_torque_estimate(time_s: np.ndarray, torque_nm: np.ndarray,
                            window_s: float = TORQUE_SMOOTHING_S) -> np.ndarray:
    """The torque the reducer felt, estimated from the sensor reading (N·m).

    The forward model is hysteretic: fed the raw reading, sensor noise makes tiny load reversals that walk
    the model along minor loops, enough to name a spurious ``scale_error`` on a run without any effect (±500 N·m
    loops on the default simulated bench: 0.5″ RMS against the true twist; 0.06″ with this estimate, see
    tests/discrepancy/test_discrepancy_stored.py). A centred (zero-phase) moving average over ``window_s``
    takes out most of the noise; a play operator of three times the remaining noise then removes the reversals
    the noise still makes.
    """
    torque = np.asarray(torque_nm, dtype=float)
    dt = np.diff(time_s)
    dt = dt[np.isfinite(dt) & (dt > 0)]
    n = int(round(window_s / float(np.median(dt)))) | 1 if len(dt) and window_s > 0 else 1
    if n <= 1 or len(torque) < 2 * n:
        return torque
    smooth = savgol_filter(torque, n, 1, mode="interp")  # a moving average; straight-line fits at the ends
    noise_nm = 1.4826 * float(np.median(np.abs(torque - smooth)))
    return _play(smooth, 3.0 * noise_nm / np.sqrt(n))


def _play(x: np.ndarray, half_width: float) -> np.ndarray:
    """Play (backlash) operator: the output follows x only once x has moved ``half_width`` past it."""
    if half_width <= 0:
        return x
    out = np.empty_like(x)
    y = float(x[0])
    for i, v in enumerate(x.tolist()):  # sequential by nature; about 0.3 µs a sample, once per analysis
        if v - half_width > y:
            y = v - half_width
        elif v + half_width < y:
            y = v + half_width
        out[i] = y
    return out


def resimulate(measured: Samples, reducer_name: str) -> Samples:
    """The catalogue reducer's forward model (``sim.physics.twist_arcsec``) on the measured torque trace.

    The torque is smoothed (:func:`applied_torque_estimate`). The reducer's friction (hysteresis) state at the
    start of a stored run is unknown: it depends on the tests run before it, and after a larger test it takes
    several loops to settle (a model started virgin is off by arcseconds for the whole run). The model's angle is linear in that state, so the state is fitted by least squares (one number within the
    physical ±hysteresis half-width; its influence decays over the first load reversals). The returned torque
    column is the measured one.
    """
    from sim.physics import TwistState, physics_from_spec, twist_arcsec
    from tcms_daq.config import load_reducer_catalogue

    catalogue = load_reducer_catalogue()
    if reducer_name not in catalogue:
        raise DataFormatError(f"reducer {reducer_name!r} is not in the reducer catalogue")
    params = physics_from_spec(catalogue[reducer_name])
    torque = applied_torque_estimate(measured.time_s, measured.torque_nm)
    virgin, _ = twist_arcsec(torque, params)
    # response to a unit initial hysteresis state (the model is linear in it)
    unit = twist_arcsec(torque, params, TwistState(0.0, 1.0))[0] - virgin
    half_width = params.hysteresis_half_width_arcsec
    angle = virgin
    if half_width > 0 and np.any(unit):
        # with a linear time term beside it, so a thermal drift is not taken for the settling state
        t = measured.time_s - float(np.mean(measured.time_s))
        design = np.column_stack([unit, np.ones_like(unit), t])
        (z0, _, _), *_ = np.linalg.lstsq(design, measured.angle_arcsec - virgin, rcond=None)
        angle = virgin + float(np.clip(z0, -half_width, half_width)) * unit
    return Samples(measured.time_s, measured.torque_nm, angle)


def stored_pair(run_id: str, data_dir: str | Path | None = None) -> tuple[Samples, Samples]:
    """(measured, simulated) of a stored run; raises DataFormatError for an unknown or empty run."""
    from tcms_daq.store import STORE_FILENAME, RunStore

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

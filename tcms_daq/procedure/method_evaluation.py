"""The evaluation of a turning test's record (pure): the core's evaluations and budgets
(``tcms_daq.transmission``, ``tcms_daq.uncertainty.station``) in the results contract of docs/transmission.md.

A record is a turning run's samples (``Samples``): ``time_s``, ``torque_nm`` (the loader's torque: the output
torque), ``angle_arcsec`` (the output angle, compensated), ``input_angle_arcsec`` (input arcsec) and
``input_torque_nm``. The results are one JSON-able dict: the method's headline values flat (each with its
``uncertainty`` entry), the core evaluation's own ``to_dict()`` keys beside them, and for the transmission error the
curve and the order spectrum (decimated for the pages).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from tcms_daq.config.models import ReducerSpec, StationUncertainty
from tcms_daq.errors import EvaluationError
from tcms_daq.samples import INPUT_ANGLE_COLUMN, INPUT_TORQUE_COLUMN, Samples
from tcms_daq.transmission.te import TeEvaluation, evaluate_transmission_error, te_records
from tcms_daq.transmission.torque import (
    evaluate_efficiency,
    evaluate_no_load_torque,
    evaluate_starting_torque,
)
from tcms_daq.uncertainty.station import (
    attach,
    efficiency_budgets,
    no_load_torque_budgets,
    starting_torque_budgets,
    te_budgets,
)

CURVE_POINTS_MAX = 720  # points of the TE curve per direction in the results
SPECTRUM_BINS_MAX = 2000  # bins of the order spectrum per direction in the results
NO_STATION_CHAIN = "type A only (no [uncertainty.station] declared)"


def _column(samples: Samples, name: str, method: str) -> np.ndarray:
    column = samples.extra.get(name)
    if column is None:
        raise EvaluationError(f"{method}: the record has no {name} column (the bench's second axis)")
    values = np.asarray(column, dtype=float)
    if not np.all(np.isfinite(values)):
        raise EvaluationError(f"{method}: {name} holds missing values (a channel without readings)")
    return values


def _decimate(values: np.ndarray, points: int) -> list[float]:
    idx = np.unique(np.linspace(0, values.size - 1, min(values.size, points)).astype(int))
    return [round(float(v), 4) for v in values[idx]]


def te_spectrum(time_s: np.ndarray, input_angle_arcsec: np.ndarray, output_angle_arcsec: np.ndarray, ratio: float,
                max_order: dict[str, float]) -> dict[str, dict[str, list[float]]]:
    """Each direction's amplitude spectrum (″) of the measured TE at its bins k/N (N whole output revolutions), up to
    ``max_order[direction]``: |2·DFT/n| of the even angle grid of ``te_records`` (trend and mean removed)."""
    out: dict[str, dict[str, list[float]]] = {}
    for name, record in te_records(time_s, input_angle_arcsec, output_angle_arcsec, ratio=ratio).items():
        phi = record.phi_rad - record.phi_rad.mean()
        te = record.te_arcsec - np.polyval(np.polyfit(phi, record.te_arcsec, 1), phi)
        amplitude = 2.0 * np.abs(np.fft.rfft(te))[1:] / te.size
        bins = min(amplitude.size, int(max_order.get(name, amplitude.size) * record.revolutions))
        step = max(1, math.ceil(bins / SPECTRUM_BINS_MAX))
        order = (np.arange(1, bins + 1) / record.revolutions)[::step]
        out[name] = {"order": [round(float(k), 4) for k in order],
                     "amplitude_arcsec": [round(float(a), 4) for a in amplitude[:bins:step]]}
    return out


def _te_results(ev: TeEvaluation, samples: Samples, chain: StationUncertainty | None,
                reducer: ReducerSpec) -> dict[str, Any]:
    teeth = reducer.kinematics.teeth(reducer.kind) if reducer.kinematics is not None else None
    t, a_in, a_out = samples.time_s, _column(samples, INPUT_ANGLE_COLUMN, "transmission-error"), samples.angle_arcsec
    attach(ev, te_budgets(t, a_in, a_out, ev, chain, teeth=teeth))
    out = ev.to_dict(curve=True)
    for name, d in out["per_direction"].items():
        out[f"{name}_transmission_error_arcsec"] = d["transmission_error_arcsec"]
    out["te_curve"] = {}
    for name, d in out["per_direction"].items():
        curve = d.pop("curve")
        out["te_curve"][name] = {k: _decimate(np.asarray(v), CURVE_POINTS_MAX) for k, v in curve.items()}
    band = {name: d.samples / d.revolutions / 4.0 for name, d in ev.per_direction.items()}
    out["te_spectrum"] = te_spectrum(t, a_in, a_out, ev.ratio, band)
    return out


def evaluate_method(samples: Samples, method: str, reducer: ReducerSpec, parameters: dict[str, Any], *,
                    chain: StationUncertainty | None = None, source: str | None = None) -> dict[str, Any]:
    """The results of a turning test's record (module docstring); ``chain``: the declared ``[uncertainty.station]``
    (None or nothing declared: the record's Type A alone), ``source`` where it was declared. Raises
    EvaluationError (one line) when the record cannot be evaluated."""
    declared = chain if chain is not None and chain.declared() else None
    t = samples.time_s
    if method == "transmission-error":
        if reducer.ratio is None or not reducer.ratio > 0:
            raise EvaluationError(f"transmission-error: {reducer.name} has no ratio in the catalogue")
        teeth = reducer.kinematics.teeth(reducer.kind) if reducer.kinematics is not None else None
        ev = evaluate_transmission_error(t, _column(samples, INPUT_ANGLE_COLUMN, method), samples.angle_arcsec,
                                         ratio=reducer.ratio, teeth=teeth)
        out = _te_results(ev, samples, declared, reducer)
    elif method == "starting-torque":
        tin, ain = _column(samples, INPUT_TORQUE_COLUMN, method), _column(samples, INPUT_ANGLE_COLUMN, method)
        sev = evaluate_starting_torque(t, tin, ain)
        attach(sev, starting_torque_budgets(t, tin, ain, sev, declared))
        out = sev.to_dict()
        out.update(sev.values())
    elif method == "no-load-torque":
        tin, ain = _column(samples, INPUT_TORQUE_COLUMN, method), _column(samples, INPUT_ANGLE_COLUMN, method)
        speeds = [float(v) for v in parameters.get("speeds_rpm", [])]
        nev = evaluate_no_load_torque(t, tin, ain, speeds_rpm=speeds)
        attach(nev, no_load_torque_budgets(t, tin, ain, nev, declared))
        out = nev.to_dict()
        out.update(nev.values())
        out["speeds_rpm"] = speeds
    elif method == "efficiency":
        tin, ain = _column(samples, INPUT_TORQUE_COLUMN, method), _column(samples, INPUT_ANGLE_COLUMN, method)
        eev = evaluate_efficiency(t, tin, ain, samples.torque_nm, samples.angle_arcsec)
        attach(eev, efficiency_budgets(t, tin, ain, samples.torque_nm, samples.angle_arcsec, eev, declared))
        out = eev.to_dict()
        out.update(eev.values())
    else:
        raise EvaluationError(f"unknown turning method {method!r}")
    out["method"] = method
    out["reducer"] = reducer.name
    out["ratio"] = reducer.ratio
    out["parameters"] = dict(parameters)
    out["uncertainty_basis"] = (f"declared chain: [uncertainty.station] of {source or 'the bench config'}"
                                if declared is not None else NO_STATION_CHAIN)
    return out

"""A turning test's results as the pages, the certificate, the exports and OPC UA show them (docs/transmission.md,
the results contract): which results it has, each with its unit and the key of its U (:func:`quantities`); its
transmission-error lines (:func:`te_lines`); and its curves (:func:`method_curves`): the transmission error against
the output angle and its order spectrum, each starting-torque ramp around its breakaway, the no-load torque per
speed, the efficiency per direction.

Pure functions over a run's results dict and its stored columns (numpy); one definition the dashboard (``GET
/api/tests/{id}/curves``), the certificate's figure and OPC UA share. Conventions are the contract's: angles in
arcsec (the input's in input arcsec), torques in N·m (the input torque turns the input forward), speeds in rpm of
the input, efficiency as a ratio (1 = 100 %).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from tcms_daq.identity import TURNING_METHODS

DIRECTIONS = ("forward", "reverse")
RAMP_POINTS = 400  # at most this many samples of each starting-torque ramp
RAMP_AFTER_S = 0.4  # clock seconds shown after a breakaway
RAMP_BEFORE_S = 0.05  # … and before the ramp began (where the input torque last stood within RAMP_START_SHARE
RAMP_START_SHARE = 0.02  # of the starting torque), at most twice the ramp's own length (its torque over its rate)


@dataclass(frozen=True)
class Quantity:
    """One result of a turning test: its key in the results (and in ``uncertainty``), the catalogue's label
    (``q_<label>``, with ``{speed}`` for a no-load torque), its unit as the results state it, the direction it
    belongs to (None: both), the input speed (no-load torque) and its OPC UA browse name."""

    key: str
    label: str
    unit: str
    direction: str | None = None
    speed_rpm: float | None = None
    browse_name: str = ""


def method_of(results: Mapping[str, Any] | None) -> str | None:
    """The turning method of a run's results (``results["method"]``); None for the stiffness test."""
    method = (results or {}).get("method")
    return str(method) if method in TURNING_METHODS else None


def _number(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    return float(value) if math.isfinite(value) else None


def speeds_of(results: Mapping[str, Any]) -> list[float]:
    """The no-load test's input speeds (rpm) as its results list them."""
    listed = results.get("speeds_rpm")
    return [float(n) for n in listed if _number(n) is not None] if isinstance(listed, list) else []


_NAMED = {
    "transmission-error": ("transmission_error_arcsec", "arcsec", "TransmissionError"),
    "starting-torque": ("starting_torque_nm", "N·m", "StartingTorque"),
}


def quantities(results: Mapping[str, Any] | None) -> list[Quantity]:
    """The results of a turning test that carry an uncertainty, in the order people read them: the headline (the
    larger direction's) first, then each direction; a no-load torque per speed; the efficiency per direction.
    Empty for the stiffness test."""
    results = results or {}
    method = method_of(results)
    if method in _NAMED:
        key, unit, name = _NAMED[method]
        return [Quantity(key, key, unit, None, None, name)] + [
            Quantity(f"{d}_{key}", f"{d}_{key}", unit, d, None, f"{name}{d.capitalize()}") for d in DIRECTIONS]
    if method == "no-load-torque":
        out = []
        for n in speeds_of(results):
            suffix = f"@{n:g}rpm"
            out.append(Quantity(f"no_load_torque_nm{suffix}", "no_load_torque_nm", "N·m", None, n,
                                f"NoLoadTorque_{n:g}rpm"))
            out += [Quantity(f"{d}_no_load_torque_nm{suffix}", f"{d}_no_load_torque_nm", "N·m", d, n,
                             f"NoLoadTorque{d.capitalize()}_{n:g}rpm") for d in DIRECTIONS]
        return out
    if method == "efficiency":
        return [Quantity(f"{d}_efficiency", f"{d}_efficiency", "1", d, None, f"Efficiency{d.capitalize()}")
                for d in DIRECTIONS]
    return []


def te_order_key(order: float) -> str:
    """The ``uncertainty`` key of a transmission-error line's amplitude (the contract's ``%.4g`` of its order)."""
    return f"te_order_{order:.4g}_amplitude_arcsec"


def te_lines(results: Mapping[str, Any] | None) -> list[dict[str, Any]]:
    """The transmission-error lines of both directions combined (``te_orders``), largest first: order (per output
    revolution), component (None: an order of no component), amplitude (arcsec) with its U entry, phase (deg) with
    its standard uncertainty (k = 1), and the directions it was found in."""
    results = results or {}
    listed = results.get("te_orders")
    table = results.get("uncertainty")
    out = []
    for line in listed if isinstance(listed, list) else []:
        if not isinstance(line, Mapping) or _number(line.get("order")) is None:
            continue
        order = float(line["order"])
        entry = table.get(te_order_key(order)) if isinstance(table, Mapping) else None
        out.append({"order": order, "component": line.get("component"),
                    "amplitude_arcsec": _number(line.get("amplitude_arcsec")),
                    "uncertainty": dict(entry) if isinstance(entry, Mapping) else None,
                    "phase_deg": _number(line.get("phase_deg")), "u_phase_deg": _number(line.get("u_phase_deg")),
                    "u_order": _number(line.get("u_order")), "directions": list(line.get("directions") or [])})
    return out


def _decimated(n: int, points: int) -> np.ndarray:
    return np.unique(np.linspace(0, n - 1, min(n, points)).astype(int)) if n else np.zeros(0, dtype=int)


def starting_ramps(results: Mapping[str, Any], columns: Mapping[str, np.ndarray]) -> list[dict[str, Any]]:
    """Each starting-torque ramp around its breakaway, from the stored samples: the time from the fitted onset
    (s), the input torque (N·m, signed: a reverse ramp is negative) and the input angle (input arcsec, from its
    value at the window's start); with the ramp's direction, starting torque (N·m, a magnitude) and onset (clock
    s). A window runs from RAMP_BEFORE_S before the ramp began (the last sample before the onset with the torque
    within RAMP_START_SHARE of the starting torque of zero) to RAMP_AFTER_S after the onset."""
    time_s = np.asarray(columns.get("time_s", ()), dtype=float)
    torque = columns.get("input_torque_nm")
    angle = columns.get("input_angle_arcsec")
    out: list[dict[str, Any]] = []
    listed = results.get("ramps")
    if torque is None or angle is None or not time_s.size or not isinstance(listed, list):
        return out
    torque, angle = np.asarray(torque, dtype=float), np.asarray(angle, dtype=float)
    for ramp in listed:
        onset, level, rate = (_number(ramp.get(k)) for k in ("onset_s", "torque_nm", "rate_nm_per_s"))
        if onset is None or level is None:
            continue
        longest = 2.0 * level / rate if rate and rate > 0 else 10.0
        near = np.flatnonzero((time_s >= onset - longest) & (time_s < onset)
                              & (np.abs(torque) <= RAMP_START_SHARE * level))
        start = (time_s[near[-1]] if near.size else onset - longest) - RAMP_BEFORE_S
        inside = np.flatnonzero((time_s >= start) & (time_s <= onset + RAMP_AFTER_S)
                                & np.isfinite(torque) & np.isfinite(angle))
        rows = inside[_decimated(inside.size, RAMP_POINTS)]
        out.append({"direction": ramp.get("direction"), "torque_nm": level, "onset_s": onset,
                    "time_from_onset_s": [round(float(v), 4) for v in time_s[rows] - onset],
                    "input_torque_nm": [round(float(v), 5) for v in torque[rows]],
                    "input_angle_arcsec": [round(float(v), 2) for v in angle[rows] - (angle[rows][0] if rows.size
                                                                                     else 0.0)]})
    return out


def _with_u(results: Mapping[str, Any], key: str) -> dict[str, Any]:
    table = results.get("uncertainty")
    entry = table.get(key) if isinstance(table, Mapping) else None
    expanded = _number(entry.get("U")) if isinstance(entry, Mapping) else None
    k = _number(entry.get("k")) if isinstance(entry, Mapping) else None
    return {"value": _number(results.get(key)), "U": expanded, "k": k}


def no_load_points(results: Mapping[str, Any]) -> list[dict[str, Any]]:
    """Per input speed (rpm): the no-load torque and each direction's magnitude (N·m), each with its U and k."""
    return [{"speed_rpm": n, "no_load": _with_u(results, f"no_load_torque_nm@{n:g}rpm"),
             **{d: _with_u(results, f"{d}_no_load_torque_nm@{n:g}rpm") for d in DIRECTIONS}}
            for n in speeds_of(results)]


def efficiency_points(results: Mapping[str, Any]) -> list[dict[str, Any]]:
    """Per direction: the efficiency (1 = 100 %) with its U and k, the blocks of whole input revolutions it is the
    mean of, and the stretch's input speed (rpm), input and output torque (N·m)."""
    per = results.get("per_direction")
    out = []
    for d in DIRECTIONS:
        stretch = per.get(d) if isinstance(per, Mapping) else None
        stretch = stretch if isinstance(stretch, Mapping) else {}
        blocks = stretch.get("block_efficiencies")
        out.append({"direction": d, **_with_u(results, f"{d}_efficiency"),
                    "block_efficiencies": [float(b) for b in blocks if _number(b) is not None]
                    if isinstance(blocks, list) else [],
                    **{k: _number(stretch.get(k)) for k in ("input_speed_rpm", "input_torque_nm", "output_torque_nm",
                                                            "revolutions")}})
    return out


def method_curves(results: Mapping[str, Any] | None, columns: Mapping[str, np.ndarray] | None = None
                  ) -> dict[str, Any]:
    """What a turning test's figure draws: ``{"method": …, "quantities": [...]}`` (:func:`quantities`) and, per
    method, ``te_curve``, ``te_spectrum`` and ``te_lines`` (transmission error), ``ramps`` (starting torque, from
    ``columns``), ``speeds`` (no-load torque) or ``directions`` (efficiency). ``{"method": "stiffness"}`` for a
    stiffness test."""
    results = results or {}
    method = method_of(results)
    if method is None:
        return {"method": "stiffness"}
    out: dict[str, Any] = {"method": method, "quantities": [asdict(q) for q in quantities(results)]}
    if method == "transmission-error":
        out.update(te_curve=results.get("te_curve") or {}, te_spectrum=results.get("te_spectrum") or {},
                   te_lines=te_lines(results))
    elif method == "starting-torque":
        out["ramps"] = starting_ramps(results, columns or {})
    elif method == "no-load-torque":
        out["speeds"] = no_load_points(results)
    else:
        out["directions"] = efficiency_points(results)
    return out

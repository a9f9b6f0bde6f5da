"""A test's identity and headline results as they leave the bench: exports, the certificate, OPC UA, the fleet.

Pure functions over the plain dicts a run record holds (its request, its results, its bench); nothing here reads a
file or the store. Results are rendered as "value ± U (k = …)" when the evaluation stated an expanded uncertainty
for them (the ``uncertainty`` entry of the shared result contract), rounded to two significant digits of U, and
as "value (U not stated)" otherwise; results without these keys (older runs) render all the same.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from tcms_daq.analysis.evaluation import decision_of
from tcms_daq.analysis.rounding import with_uncertainty


@dataclass(frozen=True)
class Headline:
    """One headline result: its key in the results dict, a label for people, its unit."""

    key: str
    label: str
    unit: str


HEADLINES: tuple[Headline, ...] = (
    Headline("rigidity_nm_per_arcmin", "torsional rigidity", "N·m/arcmin"),
    Headline("lost_motion_arcsec", "lost motion", "arcsec"),
    Headline("backlash_arcsec", "backlash", "arcsec"),
)
#: the headline results of the turning tests (docs/transmission.md, the results contract); the no-load torque's are
#: one per speed (``no_load_torque_nm@<n>rpm``: :func:`method_headlines`)
METHOD_HEADLINES: dict[str, tuple[Headline, ...]] = {
    "transmission-error": (Headline("transmission_error_arcsec", "transmission error", "arcsec"),
                           Headline("forward_transmission_error_arcsec", "transmission error, forward", "arcsec"),
                           Headline("reverse_transmission_error_arcsec", "transmission error, reverse", "arcsec")),
    "starting-torque": (Headline("starting_torque_nm", "starting torque", "N·m"),
                        Headline("forward_starting_torque_nm", "starting torque, forward", "N·m"),
                        Headline("reverse_starting_torque_nm", "starting torque, reverse", "N·m")),
    "no-load-torque": (),
    "efficiency": (Headline("forward_efficiency", "efficiency, forward", "1"),
                   Headline("reverse_efficiency", "efficiency, reverse", "1")),
}


def method_headlines(results: Mapping[str, Any] | None) -> tuple[Headline, ...]:
    """The headline results of a run: the stiffness test's, or its turning method's (``results["method"]``)."""
    method = (results or {}).get("method")
    if method not in METHOD_HEADLINES:
        return HEADLINES
    if method == "no-load-torque":
        speeds = (results or {}).get("speeds_rpm") or []
        return tuple(Headline(f"no_load_torque_nm@{float(n):g}rpm", f"no-load torque at {float(n):g} rpm", "N·m")
                     for n in speeds if isinstance(n, int | float) and not isinstance(n, bool))
    return METHOD_HEADLINES[str(method)]



def _number(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    return float(value) if math.isfinite(value) else None


def uncertainty_entry(results: Mapping[str, Any] | None, key: str) -> dict[str, Any] | None:
    """The ``uncertainty[key]`` entry of a results dict when it states a finite expanded uncertainty U ≥ 0."""
    table = (results or {}).get("uncertainty")
    entry = table.get(key) if isinstance(table, Mapping) else None
    if not isinstance(entry, Mapping):
        return None
    expanded = _number(entry.get("U"))
    if expanded is None or expanded < 0:
        return None
    return dict(entry)


def expanded_uncertainty(results: Mapping[str, Any] | None, key: str) -> float | None:
    """U of result ``key`` (in the result's unit), None when not stated."""
    entry = uncertainty_entry(results, key)
    return None if entry is None else float(entry["U"])


def format_result(results: Mapping[str, Any] | None, key: str, unit: str = "") -> str:
    """``"293.9 ± 2.3 N·m/arcmin (k = 2.05)"`` when U is stated, ``"293.94 N·m/arcmin (U not stated)"``
    otherwise, ``"—"`` when there is no finite value (the one rendering: ``analysis.rounding``)."""
    value = _number((results or {}).get(key))
    if value is None:
        return "—"
    return with_uncertainty(value, uncertainty_entry(results, key), unit)


def decision(results: Mapping[str, Any] | None) -> str | None:
    """The verdict's decision: ``pass`` | ``fail`` | ``undecided`` (ISO 14253-1), from ``verdict.decision`` when
    the evaluation states one, else from ``verdict.passed`` (older runs); None when there is no verdict."""
    if not isinstance(results, Mapping):
        return None
    verdict = results.get("verdict")
    stated = decision_of(verdict) if isinstance(verdict, Mapping) else None
    return stated if stated is not None else decision_of({"passed": results.get("passed")})


def decision_rule(results: Mapping[str, Any] | None) -> str:
    """The decision rule in words: ``guarded`` acceptance (ISO 14253-1 guard bands of U) or ``simple``."""
    verdict = (results or {}).get("verdict")
    rule = verdict.get("rule") if isinstance(verdict, Mapping) else None
    if rule == "guarded":
        return ("guarded acceptance (ISO 14253-1): a result passes only when value ± U lies within its limits, "
                "fails when value ± U lies outside them, and is undecided otherwise")
    if rule == "simple":
        return "simple acceptance: the measured value against its limits (measurement uncertainty not applied)"
    return "simple acceptance: the measured value against its limits (no decision rule stated with the results)"


def headline_results(results: Mapping[str, Any] | None) -> dict[str, dict[str, Any]]:
    """Each headline result: value, standard uncertainty u, expanded uncertainty U, coverage factor k, unit and the
    rendered text."""
    out: dict[str, dict[str, Any]] = {}
    for h in method_headlines(results):
        entry = uncertainty_entry(results, h.key)
        out[h.key] = {
            "label": h.label,
            "value": _number((results or {}).get(h.key)),
            "u": None if entry is None else _number(entry.get("u")),
            "U": None if entry is None else float(entry["U"]),
            "k": None if entry is None else _number(entry.get("k")),
            "unit": h.unit,
            "text": format_result(results, h.key, h.unit),
        }
    return out


#: the test methods a result can come from: one position, several output positions (GB/T 40731), several rates
TEST_METHODS: tuple[str, ...] = ("single", "positions", "rates")
#: … and the turning tests (the request's ``method``; GB/T 35089 §7–8)
TURNING_METHODS: tuple[str, ...] = ("transmission-error", "starting-torque", "no-load-torque", "efficiency")


def test_method(request: Mapping[str, Any], profile: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """How the result was obtained: ``{"kind": "single" | "positions" | "rates", "stages": N, "series": key}``.

    A test at N positions reports the worst of N (GB/T 40731), which is a different quantity from one position's
    value, so results of different kinds, or of different N, are not one statistical series: ``series``
    (``"single"``, ``"positions-4"``, ``"rates-3"``) names the series a result belongs to (SPC)."""
    turning = request.get("method") or (profile or {}).get("method")
    if turning in TURNING_METHODS:
        return {"kind": turning, "stages": 1, "series": turning}
    plan = (profile or {}).get("plan")
    kind = plan if plan in TEST_METHODS else (
        "positions" if request.get("positions") is not None else "rates" if request.get("rates") is not None
        else "single")
    stages = 1
    if kind == "positions":
        listed = (profile or {}).get("positions_deg")
        spec = request.get("positions")
        stages = len(listed) if isinstance(listed, list) else (
            spec if isinstance(spec, int) and not isinstance(spec, bool) else len(spec) if isinstance(spec, list)
            else 0)
    elif kind == "rates":
        listed = (profile or {}).get("rates_nm_per_s") or request.get("rates")
        stages = len(listed) if isinstance(listed, list) else 0
    return {"kind": kind, "stages": stages, "series": kind if kind == "single" else f"{kind}-{stages}"}


def run_parameters(request: Mapping[str, Any], profile: Mapping[str, Any] | None) -> dict[str, Any]:
    """The parameters a result depends on: test torque, loops, profile, torque rate, steps and dwell, and for a
    plan of several stages its output positions (deg) or loading rates (N·m/s) and the speed of the moves."""
    if test_method(request, profile)["kind"] in TURNING_METHODS:  # what the turning test's procedure ran
        ran = (profile or {}).get("parameters")
        return dict(ran) if isinstance(ran, Mapping) else {
            k: request[k] for k in ("input_speed_rpm", "load_torque_nm", "revolutions", "ramps", "creep_deg_per_s",
                                    "speeds_rpm", "dwell_s") if request.get(k) is not None}
    keys = ("max_torque_nm", "cycles", "profile", "rate_nm_per_s", "step_nm", "dwell_s")
    params = {k: request[k] for k in keys if request.get(k) is not None}
    for key in ("rate_nm_per_s", "conditioning_loops", "tip_dwell_s", "start", "decision_rule"):
        if profile and profile.get(key) is not None and key not in params:
            params[key] = profile[key]
    if request.get("decision_rule") is not None:
        params["decision_rule"] = request["decision_rule"]
    method = test_method(request, profile)
    if method["kind"] == "positions":
        listed = (profile or {}).get("positions_deg")
        params["positions_deg"] = listed if isinstance(listed, list) else _positions_deg(request.get("positions"))
        velocity = request.get("move_velocity_deg_per_s") or (profile or {}).get("move_velocity_deg_per_s")
        if velocity is not None:
            params["move_velocity_deg_per_s"] = velocity
    elif method["kind"] == "rates":
        listed = (profile or {}).get("rates_nm_per_s")
        params["rates_nm_per_s"] = listed if isinstance(listed, list) else request.get("rates")
        params.pop("rate_nm_per_s", None)  # each stage has its own
    return params


def _positions_deg(spec: Any) -> list[float] | None:
    from tcms_daq.procedure.plan import positions_from

    try:
        return positions_from(spec)
    except (TypeError, ValueError):
        return None


def _snapshot_section(snapshot: Mapping[str, Any] | None, name: str) -> Mapping[str, Any]:
    section = (snapshot or {}).get(name)
    return section if isinstance(section, Mapping) else {}


def ambient_temperature(request: Mapping[str, Any], snapshot: Mapping[str, Any] | None) -> dict[str, Any]:
    """The ambient temperature of the test (°C): the request's when it states one, else the bench configuration's
    (``[certificate] ambient_temperature_c``), else None; ``source`` says which."""
    stated = _number(request.get("ambient_temperature_c"))
    if stated is not None:
        return {"value_c": stated, "source": "request"}
    configured = _number(_snapshot_section(snapshot, "certificate").get("ambient_temperature_c"))
    if configured is not None:
        return {"value_c": configured, "source": "bench configuration"}
    return {"value_c": None, "source": None}


def run_identity(*, run_id: str, request: Mapping[str, Any], profile: Mapping[str, Any] | None,
                 results: Mapping[str, Any] | None, bench_id: str | None, bench_name: str | None,
                 status: str, started_at_iso: str | None, compensation_version: int | None,
                 compensation_sha256: str | None, config_snapshot: Mapping[str, Any] | None = None
                 ) -> dict[str, Any]:
    """Everything that names a test and its outcome, as a flat JSON-able dict (the exports' metadata).

    ``plan`` and ``user`` are the test plan and the signed-in user a run records (None until runs record them);
    ``bench_model_version`` is the bench model in use when the test started (the config snapshot's)."""
    bench_model = (config_snapshot or {}).get("bench_model_version")
    return {
        "run_id": run_id,
        "status": status,
        "reducer": request.get("reducer"),
        "serial_number": request.get("serial_number"),
        "customer": request.get("customer"),
        "order_number": request.get("order_number"),
        "operator": request.get("operator"),
        "user": request.get("user"),
        "plan": request.get("plan"),
        "bench_id": bench_id,
        "bench_name": bench_name,
        "started_at": started_at_iso,
        "method": test_method(request, profile),
        "parameters": run_parameters(request, profile),
        "ambient_temperature": ambient_temperature(request, config_snapshot),
        "compensation_version": compensation_version,
        "compensation_sha256": compensation_sha256,
        "bench_model_version": bench_model if isinstance(bench_model, int) and not isinstance(bench_model, bool)
        else None,
        "verdict": decision(results),
        "results": headline_results(results),
    }


PARAMETER_LABELS: dict[str, tuple[str, str]] = {
    "max_torque_nm": ("test torque", "N·m"),
    "cycles": ("evaluated loops", ""),
    "profile": ("profile", ""),
    "rate_nm_per_s": ("torque rate", "N·m/s"),
    "step_nm": ("torque step", "N·m"),
    "dwell_s": ("dwell per step", "s"),
    "conditioning_loops": ("conditioning loops", ""),
    "tip_dwell_s": ("dwell at ±T", "s"),
    "start": ("first load direction", ""),
    "decision_rule": ("decision rule", ""),
    "positions_deg": ("output positions", "°"),
    "move_velocity_deg_per_s": ("output speed between positions", "°/s"),
    "rates_nm_per_s": ("loading rates", "N·m/s"),
    "input_speed_rpm": ("input speed", "rpm"),
    "load_torque_nm": ("load torque", "N·m"),
    "revolutions": ("output revolutions per direction", ""),
    "ramps": ("breakaways per direction", ""),
    "creep_deg_per_s": ("creep velocity", "°/s"),
    "turn_deg": ("creep stops after", "°"),
    "speeds_rpm": ("input speeds", "rpm"),
}


def parameter_text(parameters: Mapping[str, Any]) -> list[str]:
    """``["test torque 500 N·m", "evaluated loops 3", …]`` in the order of :data:`PARAMETER_LABELS`."""
    out = []
    for key, (label, unit) in PARAMETER_LABELS.items():
        if key in parameters:
            value = parameters[key]
            shown = (", ".join(f"{v:g}" for v in value) if isinstance(value, list)
                     else f"{value:g}" if isinstance(value, float) else str(value))
            out.append(f"{label} {shown}{' ' + unit if unit else ''}")
    return out


def identity_lines(identity: Mapping[str, Any]) -> list[str]:
    """The identity of :func:`run_identity` as lines for people (file comments, logs)."""
    bench = identity.get("bench_name") or "—"
    if identity.get("bench_id"):
        bench += f" (id {identity['bench_id']})"
    version = identity.get("compensation_version")
    compensation = (f"version {version}" if version is not None else "version not recorded") + (
        f", sha256 {str(identity['compensation_sha256'])[:12]}" if identity.get("compensation_sha256") else "")
    model = identity.get("bench_model_version")
    method = identity.get("method") or {}
    lines = [
        f"run {identity.get('run_id')} ({identity.get('status')}), started {identity.get('started_at') or '—'} UTC",
        f"reducer {identity.get('reducer') or '—'}, serial number {identity.get('serial_number') or '—'}",
        f"bench {bench}, operator {identity.get('operator') or '—'}",
        f"customer {identity.get('customer') or '—'}, order {identity.get('order_number') or '—'}",
        f"method: {method.get('kind') or 'single'}" + (f", {method.get('stages')} stages"
                                                        if method.get("kind") in ("positions", "rates") else ""),
        "parameters: " + (", ".join(parameter_text(identity.get("parameters") or {})) or "—"),
        f"compensation: {compensation}; bench model version {model if model is not None else '—'}",
    ]
    results = identity.get("results") or {}
    lines += [f"{r['label']}: {r['text']}" for r in results.values() if isinstance(r, Mapping)]
    lines.append(f"verdict: {identity.get('verdict') or 'none'}")
    return lines

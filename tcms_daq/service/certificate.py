"""The PDF test certificate of a stored run (``GET /api/tests/{id}/certificate.pdf``, ``tcms certificate``).

Identity (reducer, serial number, bench, operator, start), test parameters, the hysteresis curve, the results
± U with the decision rule and every check, the verdict, the measuring chain with its calibration, and the
compensation version. Typeset by Typst through its Python package (``typst``): a compiler in a wheel, offline,
no system libraries or fonts needed (it embeds its own), deterministic; the template
(``certificate.typ``) takes every value as data through ``sys.inputs``, so no text a user typed is read as
markup. The plot is the HTML report's (matplotlib SVG, glyphs as paths).
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from datetime import UTC, datetime
from importlib import resources
from typing import Any

import numpy as np

from tcms_daq import __version__
from tcms_daq.analysis.evaluation import decision_of
from tcms_daq.analysis.rounding import NOT_STATED
from tcms_daq.errors import TcmsError
from tcms_daq.identity import HEADLINES, PARAMETER_LABELS, decision, decision_rule, format_result
from tcms_daq.service.report import hysteresis_svg
from tcms_daq.store import StoredRun

TEMPLATE = "certificate.typ"
KINDS = {"angle": "angle encoder", "torque": "torque sensor", "loader": "servo loader"}


class CertificateError(TcmsError):
    """The certificate could not be typeset."""


def _text(value: Any, default: str = "—") -> str:
    if value is None or value == "":
        return default
    if isinstance(value, float):
        return f"{value:.6g}"
    return str(value)


def _results_rows(results: Mapping[str, Any]) -> list[dict[str, str]]:
    """Headline results first, then any other result the uncertainty table states."""
    found = results.get("uncertainty")
    table: Mapping[str, Any] = found if isinstance(found, Mapping) else {}
    rows = []
    keys = [(h.key, h.label, h.unit) for h in HEADLINES]
    keys += [(k, k.replace("_", " "), str((table.get(k) or {}).get("unit", ""))) for k in table
             if k not in {h.key for h in HEADLINES} and isinstance(results.get(k), int | float)]
    for key, label, unit in keys:
        entry = table.get(key)
        dominant = entry.get("dominant") if isinstance(entry, Mapping) else None
        rows.append({"label": label, "text": format_result(results, key, unit),
                     "dominant": _text(dominant, "—" if entry else NOT_STATED)})
    return rows


def _checks(results: Mapping[str, Any]) -> list[dict[str, str]]:
    verdict = results.get("verdict")
    checks = verdict.get("checks") if isinstance(verdict, Mapping) else None
    rows = []
    for name, check in (checks or {}).items():
        if not isinstance(check, Mapping):
            continue
        outcome = decision_of(check) or "—"
        band = check.get("guard_band")
        rows.append({"label": _text(check.get("label") or name), "value": _text(check.get("value")),
                     "guard_band": _text(band, "none"), "decision": outcome})
    return rows


def _calibration(cal: Any) -> str:
    if not isinstance(cal, Mapping) or not any(cal.values()):
        return "not stated in the bench configuration"
    parts = []
    if cal.get("certificate"):
        parts.append(f"certificate {cal['certificate']}")
    if cal.get("laboratory"):
        parts.append(f"by {cal['laboratory']}")
    if cal.get("calibrated_on"):
        parts.append(f"calibrated {cal['calibrated_on']}")
    if cal.get("due"):
        parts.append(f"due {cal['due']}")
    if cal.get("uncertainty"):
        parts.append(f"U = {cal['uncertainty']}")
    return ", ".join(parts) or "not stated in the bench configuration"


def _instruments(snapshot: Mapping[str, Any] | None) -> list[dict[str, str]]:
    instruments = (snapshot or {}).get("instruments")
    if not isinstance(instruments, Mapping):
        return [{"kind": "—", "device": "the run recorded no bench configuration", "calibration": "—"}]
    rows = []
    for kind, cfg in instruments.items():
        if not isinstance(cfg, Mapping):
            continue
        stated = cfg.get("calibration")
        cal: Mapping[str, Any] = stated if isinstance(stated, Mapping) else {}
        device = cal.get("device") or ""
        link = f"{cfg.get('driver', '?')} at {cfg.get('url', '?')}"
        rows.append({"kind": KINDS.get(kind, str(kind)), "device": f"{device} ({link})" if device else link,
                     "calibration": _calibration(cal)})
    return rows


def certificate_document(record: StoredRun, issued_at: datetime | None = None) -> dict[str, Any]:
    """Everything the template prints, as strings (and lists of strings)."""
    ident = record.identity()
    results = record.results or {}
    issued = (issued_at or datetime.now(UTC)).astimezone(UTC)
    params = ident["parameters"]
    parameters = []
    for key, (label, unit) in PARAMETER_LABELS.items():
        if key in params:
            parameters.append([label[0].upper() + label[1:], f"{_text(params[key])}{' ' + unit if unit else ''}"])
    snapshot = record.config_snapshot or {}
    section = snapshot.get("bench")
    bench_cfg: Mapping[str, Any] = section if isinstance(section, Mapping) else {}
    version = record.compensation_version
    compensation = [
        ["Version", f"{version} (accepted upload)" if version is not None else "the bench configuration's file"],
        ["Source", _text(bench_cfg.get("compensation"), "identity (none)") if version is None else "stored version"],
        ["SHA-256 of the compensator", _text(ident.get("compensation_sha256"))],
    ]
    bench = _text(record.bench_name) + (f" (id {record.bench_id})" if record.bench_id else "")
    return {
        "run_id": record.id,
        "status": record.status,
        "error": record.error or "the test did not complete",
        "reducer": _text(ident.get("reducer")),
        "serial_number": _text(ident.get("serial_number"), "not stated"),
        "operator": _text(ident.get("operator"), "not stated"),
        "bench": bench,
        "started_at": _text(ident.get("started_at"), "never started").replace("T", " ").replace("+00:00", ""),
        "issued_at": issued.strftime("%Y-%m-%d %H:%M:%S"),
        "software_version": __version__,
        "parameters": parameters or [["—", "—"]],
        "results": _results_rows(results),
        "uncertainty_basis": _text(results.get("uncertainty_basis"), "no uncertainty evaluation recorded"),
        "decision_rule": decision_rule(results),
        "checks": _checks(results),
        "verdict": decision(results) or "none",
        "warnings": [str(w) for w in results.get("warnings") or [] if w],
        "instruments": _instruments(snapshot),
        "compensation": compensation,
    }


def render_certificate(record: StoredRun, columns: Mapping[str, np.ndarray],
                       issued_at: datetime | None = None) -> bytes:
    """The certificate as PDF bytes. CertificateError (one line) when Typst refuses."""
    import typst

    doc = certificate_document(record, issued_at)
    inputs = {"data": json.dumps(doc, allow_nan=False)}
    if len(np.asarray(columns.get("torque_nm", ()))):
        inputs["loop"] = hysteresis_svg(columns)
    template = resources.files("tcms_daq.service").joinpath(TEMPLATE).read_bytes()
    issued = (issued_at or datetime.now(UTC)).astimezone(UTC).replace(microsecond=0)
    try:
        pdf = typst.compile(template, format="pdf", sys_inputs=inputs, ignore_system_fonts=True,
                            timestamp=issued)
    except RuntimeError as exc:  # typst.TypstError
        raise CertificateError(f"certificate of run {record.id}: {str(exc).splitlines()[0]}") from None
    assert isinstance(pdf, bytes)
    return pdf

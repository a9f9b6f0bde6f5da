"""The PDF test certificate of a stored run (``GET /api/tests/{id}/certificate.pdf``, ``tcms certificate``): a
document a customer signs.

Customer, order and the item (reducer model and serial number); the test method (the configured reference of
the test's kind, ``[certificate] method_*``), the bench, the start, the ambient temperature (the request's, else
the configuration's) and who tested; the parameters; the loop in relative twist with the evaluation's lines
(:mod:`tcms_daq.service.loop_figure`); the results ± U, and for a test at several positions or rates each stage's
results and what the summary is (the worst of N); the decision rule with every check; the instruments with their
calibration and the traceability statement; the compensation and bench model versions; approval fields.

Every number a measurement gave is rounded to its U (:mod:`tcms_daq.analysis.rounding`, the one rounding); every
word comes from the catalogue :mod:`tcms_daq.service.certificate_text`; no file path of the bench PC is printed.
Typeset by Typst through its Python package (``typst``): a compiler in a wheel, offline, no system libraries or
fonts needed (it embeds its own), deterministic; the template (``certificate.typ``) takes every value as data
through ``sys.inputs``, so no text a user typed is read as markup.
"""

from __future__ import annotations

import json
import re
from collections.abc import Mapping
from datetime import UTC, datetime
from importlib import resources
from typing import Any, cast

import numpy as np

from tcms_daq import __version__
from tcms_daq.analysis.evaluation import decision_of
from tcms_daq.analysis.rounding import round_to_uncertainty, unit_suffix, with_uncertainty
from tcms_daq.config.models import CertificateSection
from tcms_daq.errors import TcmsError
from tcms_daq.identity import HEADLINES, PARAMETER_LABELS, TURNING_METHODS, decision
from tcms_daq.service import fonts
from tcms_daq.service.certificate_text import catalogue
from tcms_daq.service.loop_figure import loop_figure_svg
from tcms_daq.service.messages import check_label, source_text, warnings_text
from tcms_daq.service.method_figure import component_words, method_figure_svg
from tcms_daq.service.method_views import method_of, quantities, te_lines
from tcms_daq.store import StoredRun

TEMPLATE = "certificate.typ"
#: results printed beside the headline ones when the evaluation gives them (with their unit)
FURTHER_RESULTS = (("positive_rigidity_nm_per_arcmin", "N·m/arcmin"), ("negative_rigidity_nm_per_arcmin", "N·m/arcmin"),
                   ("k1_nm_per_rad", "N·m/rad"), ("k2_nm_per_rad", "N·m/rad"), ("k3_nm_per_rad", "N·m/rad"),
                   ("loop_energy_j", "J"))
STAGE_COLUMNS = ("rigidity_nm_per_arcmin", "lost_motion_arcsec", "backlash_arcsec")
#: an absolute file path (POSIX or Windows); not a unit like N·m/arcmin, not a URL's //host
PATH = re.compile(r"(?<![\w:/\\])(?:[A-Za-z]:)?(?:[\\/][^\s\\/,;()]+)+")


class CertificateError(TcmsError):
    """The certificate could not be typeset."""


class MissingFont(CertificateError):
    """The certificate's language needs a font this machine does not have (a CJK font for Chinese)."""


def without_paths(text: str) -> str:
    """``text`` with every absolute file path reduced to its file name (a certificate names no path of the bench
    PC)."""
    return PATH.sub(lambda m: re.split(r"[\\/]", m.group(0))[-1], text)


def _number(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    return float(value) if np.isfinite(value) else None


def rounded(value: Any, expanded: Any) -> str:
    """A bare number rounded to the decimal place of ``expanded`` (its U; :func:`round_to_uncertainty`), or to
    four significant digits when no U is stated; "—" for no number."""
    number, u = _number(value), _number(expanded)
    if number is None:
        return "—"
    if u is None or u <= 0:
        return f"{number:.4g}"
    return round_to_uncertainty(number, u)[0]


class _Doc:
    """The certificate's words (``t``) and the run's record, shared by the pieces below."""

    def __init__(self, record: StoredRun, lang: str):
        self.record = record
        self.t = catalogue(lang)
        self.lang = lang
        self.ident = record.identity()
        self.results: Mapping[str, Any] = record.results or {}
        snapshot = record.config_snapshot or {}
        section = snapshot.get("certificate")
        self.config = CertificateSection.model_validate(section) if isinstance(section, Mapping) else \
            CertificateSection()
        self.snapshot = snapshot

    def say(self, key: str, **fields: Any) -> str:
        return self.t[key].format(**fields) if fields else self.t[key]

    def value_word(self, value: Any) -> str:
        return self.t.get(f"value_{value}", str(value)) if isinstance(value, str) else str(value)


def _uncertainty(results: Mapping[str, Any], key: str) -> Mapping[str, Any] | None:
    table = results.get("uncertainty")
    entry = table.get(key) if isinstance(table, Mapping) else None
    return entry if isinstance(entry, Mapping) else None


def with_u(d: _Doc, value: Any, entry: Mapping[str, Any] | None, unit: str) -> str:
    """"value ± U unit (k = …)" (:func:`with_uncertainty`); without a stated U four significant digits and the
    catalogue's "U not stated"; "—" without a value."""
    number = _number(value)
    if number is None:
        return "—"
    if entry is None or _number(entry.get("U")) is None:
        return f"{number:.4g}{unit_suffix(unit)} ({d.t['u_not_stated']})"
    return with_uncertainty(number, entry, unit)


def _scaled(entry: Mapping[str, Any] | None, factor: float) -> Mapping[str, Any] | None:
    """An uncertainty entry with U in another unit (an efficiency's ratio as %)."""
    if entry is None or factor == 1.0 or _number(entry.get("U")) is None:
        return entry
    return {**entry, "U": factor * float(entry["U"])}


def _method_rows(d: _Doc) -> list[dict[str, str]]:
    """A turning test's results (``method_views.quantities``): the headline, then each direction (per speed for the
    no-load torque), each as value ± U; the efficiency in %."""
    rows = []
    for q in quantities(d.results):
        entry = _uncertainty(d.results, q.key)
        factor, unit = (100.0, "%") if q.unit == "1" else (1.0, q.unit)
        value = _number(d.results.get(q.key))
        label = d.say(f"q_{q.label}", speed=f"{q.speed_rpm:g}") if q.speed_rpm is not None else d.t[f"q_{q.label}"]
        dominant = entry.get("dominant") if entry else None
        rows.append({"label": label, "text": with_u(d, None if value is None else factor * value, _scaled(entry, factor),
                                                    unit),
                     "dominant": source_text(dominant, d.lang) if dominant else ("—" if entry else d.t["u_not_stated"])})
    return rows


def _te_lines(d: _Doc) -> dict[str, Any] | None:
    """The transmission error's lines: order, component, amplitude ± U, phase (to the place of its standard
    uncertainty)."""
    lines = te_lines(d.results)
    if method_of(d.results) != "transmission-error" or not lines:
        return None

    def label(key: str, **fields: Any) -> str:
        return d.say(key, **fields)

    rows = []
    for ln in lines:
        u_phase, phase = ln["u_phase_deg"], ln["phase_deg"]
        rows.append([f"{ln['order']:.5g}",  # a line's name: its bin (u_order is a small part of one)
                     component_words(ln["component"], label),
                     with_u(d, ln["amplitude_arcsec"], ln["uncertainty"], ""),
                     "—" if phase is None else rounded(phase, u_phase)])
    return {"title": d.t["section_te_lines"], "header": [d.t["col_order"], d.t["col_component"], d.t["col_amplitude"],
                                                         d.t["col_phase"]],
            "rows": rows, "note": d.t["te_lines_note"]}


def _result_rows(d: _Doc) -> list[dict[str, str]]:
    """Headline results first, then the further results the evaluation gives with their U, each as value ± U."""
    if method_of(d.results) is not None:
        return _method_rows(d)
    rows = []
    further = [(k, u) for k, u in FURTHER_RESULTS
               if _number(d.results.get(k)) is not None and _uncertainty(d.results, k) is not None]
    for key, unit in [(h.key, h.unit) for h in HEADLINES] + further:
        entry = _uncertainty(d.results, key)
        shown = with_u(d, d.results.get(key), entry, unit)
        dominant = entry.get("dominant") if entry else None
        rows.append({"label": d.t[f"q_{key}"], "text": shown,
                     "dominant": source_text(dominant, d.lang) if dominant else ("—" if entry else d.t["u_not_stated"])})
    return rows


def _stages(d: _Doc) -> dict[str, Any] | None:
    """The per-position or per-rate table: each stage's results (the cell the summary takes in bold), the summary
    row (the worst of N) and the spread (and, for rates, the change per tenfold rate) rounded to the U's place."""
    positional = isinstance(d.results.get("positions"), list) and bool(d.results.get("positions"))
    listed = d.results.get("positions") if positional else d.results.get("rates")
    if not isinstance(listed, list) or not listed:
        return None
    entries = [e for e in listed if isinstance(e, Mapping)]
    summary_values = {key: _number(d.results.get(key)) for key in STAGE_COLUMNS}
    rows = []
    taken: set[str] = set()
    for e in entries:
        where = _number(e.get("position_deg") if positional else e.get("rate_nm_per_s"))
        cells = [{"text": "—" if where is None else f"{where:g}", "bold": False}]
        for key in STAGE_COLUMNS:
            value = _number(e.get(key))
            worst = value is not None and value == summary_values[key] and key not in taken
            if worst:
                taken.add(key)
            cells.append({"text": with_u(d, value, _uncertainty(e, key), ""), "bold": worst})
        rows.append(cells)
    worst_row = [d.say("row_worst", n=len(entries))] + [
        with_u(d, d.results.get(key), _uncertainty(d.results, key), "") for key in STAGE_COLUMNS]
    extra = [[d.t["row_spread"]] + [rounded(d.results.get(f"{key}_spread"), (_uncertainty(d.results, key) or {})
                                            .get("U")) for key in STAGE_COLUMNS]]
    sensitivity = d.results.get("rate_sensitivity")
    if not positional and isinstance(sensitivity, Mapping):
        extra.append([d.t["row_per_decade"]] + [
            rounded(sensitivity.get(f"{key}_per_decade"), (_uncertainty(d.results, key) or {}).get("U"))
            for key in STAGE_COLUMNS])
    return {"title": d.t["section_positions" if positional else "section_rates"],
            "header": [d.t["col_position" if positional else "col_rate"], d.t["col_rigidity"],
                       d.t["col_lost_motion"], d.t["col_backlash"]],
            "rows": rows, "worst": worst_row, "extra": extra}


def _checks(d: _Doc) -> list[dict[str, str]]:
    verdict = d.results.get("verdict")
    checks = verdict.get("checks") if isinstance(verdict, Mapping) else None
    rows = []
    for name, check in (checks or {}).items():
        if not isinstance(check, Mapping):
            continue
        expanded = check.get("U") if check.get("U") is not None else check.get("guard_band")
        band = _number(check.get("guard_band"))
        rows.append({"label": check_label(check, d.lang) or str(name), "value": rounded(check.get("value"), expanded),
                     "guard_band": d.t["guard_none"] if not band else round_to_uncertainty(band, band)[1],
                     "decision": decision_of(check) or "none",
                     "decision_text": d.t.get(f"decision_{decision_of(check) or 'none'}", "—")})
    return rows


def _rule(d: _Doc) -> str:
    verdict = d.results.get("verdict")
    rule = verdict.get("rule") if isinstance(verdict, Mapping) else None
    return d.t["rule_guarded"] if rule == "guarded" else d.t["rule_simple"] if rule == "simple" else \
        d.t["rule_unstated"]


def _calibration(d: _Doc, cal: Mapping[str, Any]) -> str:
    parts = [d.say(f"cal_{key}", value=cal[key]) for key in ("certificate", "laboratory", "calibrated_on", "due",
                                                              "uncertainty") if cal.get(key)]
    return ", ".join(parts) or d.t["cal_not_stated"]


def _instruments(d: _Doc) -> list[dict[str, str]]:
    instruments = d.snapshot.get("instruments")
    if not isinstance(instruments, Mapping):
        return [{"kind": "—", "device": d.t["no_config"], "calibration": "—"}]
    rows = []
    for kind, cfg in instruments.items():
        if not isinstance(cfg, Mapping):
            continue
        stated = cfg.get("calibration")
        cal: Mapping[str, Any] = stated if isinstance(stated, Mapping) else {}
        driver = str(cfg.get("driver") or "?")
        device = d.say("device_driver", device=cal["device"], driver=driver) if cal.get("device") else \
            d.say("device_unnamed", driver=driver)
        rows.append({"kind": d.t.get(f"kind_{kind}", str(kind)), "device": device,
                     "calibration": _calibration(d, cal)})
    return rows


def _parameters(d: _Doc) -> list[list[str]]:
    params = d.ident.get("parameters") or {}
    turning = (d.ident.get("method") or {}).get("kind") in TURNING_METHODS
    out = []
    for key, (_, unit) in PARAMETER_LABELS.items():
        if key not in params or params[key] is None:
            continue
        value = params[key]
        shown = ", ".join(f"{float(v):g}" for v in value) if isinstance(value, list) else \
            f"{value:g}" if isinstance(value, float) else d.value_word(value)
        name = "param_hold_s" if turning and key == "dwell_s" else f"param_{key}"  # a turning test holds a speed
        out.append([d.t.get(name, key), shown + (unit_suffix(unit) if unit not in ("", "°") else
                                                 "°" if unit == "°" else "")])
    return out or [["—", "—"]]


def _ambient(d: _Doc) -> str:
    ambient = d.ident.get("ambient_temperature") or {}
    value = _number(ambient.get("value_c"))
    if value is None:
        return d.t["ambient_not_recorded"]
    source = d.t["ambient_source_request"] if ambient.get("source") == "request" else d.t["ambient_source_config"]
    return d.say("ambient_value", value=f"{value:g}", source=source)


def certificate_document(record: StoredRun, issued_at: datetime | None = None, lang: str = "en") -> dict[str, Any]:
    """Everything the template prints, as strings (and lists of strings), and the catalogue ``t`` it labels
    them with."""
    d = _Doc(record, lang)
    ident, t = d.ident, d.t
    issued = (issued_at or datetime.now(UTC)).astimezone(UTC)
    method = ident.get("method") or {}
    kind = str(method.get("kind") or "single")
    stage_word = {"positions": ("stage_position", "stage_positions"), "rates": ("stage_rate", "stage_rates")}
    bench = str(record.bench_name or "—") + (f" ({d.say('bench_id', bench_id=record.bench_id)})"
                                              if record.bench_id else "")
    bench_section = d.snapshot.get("bench")
    nameplate = bench_section if isinstance(bench_section, Mapping) else {}
    model = " ".join(str(nameplate[k]) for k in ("manufacturer", "model", "serial_number") if nameplate.get(k))
    if model:
        bench += f", {model}"
    started = ident.get("started_at")
    version, model_version = ident.get("compensation_version"), ident.get("bench_model_version")
    turning = kind in TURNING_METHODS
    if kind in stage_word:
        one, many = (t[k] for k in stage_word[kind])
        summary = d.say("summary_stages", n=method.get("stages"), stages=many, stage=one)
        caption = d.say("loop_caption_stages", stage=one)
    elif turning:
        summary, caption = t[f"summary_{kind}"], t[f"caption_{kind}"]
    else:
        summary, caption = t["summary_single"], t["loop_caption"]
    verdict = decision(d.results) or "none"
    basis = d.results.get("uncertainty_basis")
    return {
        "t": t,
        "run_id": record.id,
        "status": record.status,
        "not_completed": d.say("not_completed", status=record.status, error=record.error or t["not_completed_error"]),
        "footer": d.say("footer", run_id=record.id, issued_at=issued.strftime("%Y-%m-%d %H:%M:%S"),
                        software_version=__version__),
        "issued_date": issued.strftime("%Y-%m-%d"),
        "laboratory": d.config.laboratory or "",
        "item": [[t["customer"], ident.get("customer") or t["not_stated"]],
                 [t["order_number"], ident.get("order_number") or t["not_stated"]],
                 [t["reducer"], ident.get("reducer") or "—"],
                 [t["serial_number"], ident.get("serial_number") or t["not_stated"]]],
        "subtitle": t[f"subtitle_{kind}"] if turning else t["subtitle"],
        "figure_title": t[f"figure_{kind}"] if turning else t["section_loop"],
        "test": [[t["method"], t[f"method_{kind}"] if turning  # (the config's method_* name the stiffness tests')
                  else d.config.method(kind) or t.get(f"method_{kind}", t["method_single"])],
                 [t["bench"], bench],
                 [t["started"], (str(started).replace("T", " ").replace("+00:00", "")[:19] + " " + t["utc"])
                  if started else t["never_started"]],
                 [t["ambient"], _ambient(d)],
                 [t["tested_by"], ident.get("operator") or t["not_stated"]]],
        "parameters": _parameters(d),
        "loop_caption": caption,
        "results": _result_rows(d),
        "summary": summary,
        "u_note": d.say("u_note", basis=without_paths(source_text(basis, d.lang)) if basis else t["basis_none"]),
        "stages": _stages(d),
        "te_lines": _te_lines(d),
        "has_limits": not turning or decision(d.results) is not None,
        "decision_rule": _rule(d),
        "checks": _checks(d),
        "verdict": verdict,
        "verdict_text": t.get(f"decision_{verdict}", verdict).upper(),
        "warnings": [without_paths(w) for w in warnings_text(d.results, d.lang) if w],
        "instruments": _instruments(d),
        "traceability": d.config.traceability or t["traceability_default"],
        "compensation": [[t["compensation_version"], str(version) if version is not None else t["not_recorded"]],
                         [t["compensation_sha"], str(ident.get("compensation_sha256") or t["not_recorded"])],
                         [t["bench_model_version"], str(model_version) if model_version is not None
                          else t["not_recorded"]],
                         [t["software"], f"TCMS-DAQ {__version__}"]],
        "tested_by": ident.get("operator") or "",
    }


def render_certificate(record: StoredRun, columns: Mapping[str, np.ndarray],
                       issued_at: datetime | None = None, lang: str = "en") -> bytes:
    """The certificate as PDF bytes. CertificateError (one line) when Typst refuses."""
    import typst

    doc = certificate_document(record, issued_at, lang)
    font_paths: list[str] = []
    families = ["DejaVu Sans"]
    if lang != "en":  # Typst's embedded fonts have no CJK glyphs: an installed CJK font after the Latin one
        cjk = fonts.cjk_fonts()
        if not cjk:
            raise MissingFont(f"certificate of run {record.id} in {lang!r}: no CJK font installed "
                                   "(Debian: apt-get install fonts-noto-cjk)")
        doc["fonts"] = [cjk[0][0]]
        doc["lang"] = lang
        font_paths.append(str(cjk[0][1].parent))
        families = fonts.figure_families()
    inputs = {"data": json.dumps(doc, allow_nan=False)}
    t = doc["t"]
    import matplotlib

    def label(key: str, **f: Any) -> str:
        return t[key].format(**f) if f else t[key]

    def shown(value: float, expanded: float | None) -> str:
        return with_uncertainty(value, None if expanded is None else {"U": expanded}, "%")

    with matplotlib.rc_context({"font.family": families}):
        figure = method_figure_svg(record.results, columns, label, shown) if method_of(record.results) else \
            loop_figure_svg(columns, record.results, label)
    if figure is not None:
        inputs["loop"] = figure
    template = resources.files("tcms_daq.service").joinpath(TEMPLATE).read_bytes()
    issued = (issued_at or datetime.now(UTC)).astimezone(UTC).replace(microsecond=0)
    try:
        pdf = typst.compile(template, format="pdf", sys_inputs=inputs, ignore_system_fonts=True,
                            font_paths=cast(Any, font_paths), timestamp=issued)  # paths beside a bytes template
    except RuntimeError as exc:  # typst.TypstError
        raise CertificateError(f"certificate of run {record.id}: {str(exc).splitlines()[0]}") from None
    assert isinstance(pdf, bytes)
    return pdf

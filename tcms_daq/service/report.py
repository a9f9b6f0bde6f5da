"""The HTML report of one run: request, outcome, the hysteresis plot (inline SVG) and the results table, in the
language asked for (``?lang=``): every word from the message catalogue (:mod:`tcms_daq.service.messages`)."""

from __future__ import annotations

import html
import io
from collections.abc import Mapping
from typing import Any

import numpy as np

from tcms_daq.analysis.evaluation import decision_of
from tcms_daq.analysis.rounding import NOT_STATED, with_uncertainty
from tcms_daq.service.loop_figure import evaluated_mask
from tcms_daq.service.messages import check_label, reasons_text, rule_text, source_text, text, warnings_text
from tcms_daq.store import StoredRun
from tcms_daq.units import ARCSEC_PER_ARCMIN

MAX_PLOT_POINTS = 20_000


def hysteresis_svg(columns: Mapping[str, np.ndarray], lang: str = "en") -> str:
    """Angle (arcmin) against torque (N·m), compensated and raw; decimated to at most MAX_PLOT_POINTS."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.figure import Figure

    from tcms_daq.service.fonts import figure_families

    with matplotlib.rc_context({"font.family": figure_families() if lang != "en" else ["DejaVu Sans"]}):
        return _hysteresis_svg(columns, lang, Figure)


def _hysteresis_svg(columns: Mapping[str, np.ndarray], lang: str, Figure: Any) -> str:
    def t(key: str) -> str:
        return text(key, lang)

    torque = np.asarray(columns.get("torque_nm", np.empty(0)))
    step = max(1, len(torque) // MAX_PLOT_POINTS)
    fig = Figure(figsize=(7.0, 4.6))
    ax = fig.add_subplot()
    if "encoder_arcsec" in columns:
        ax.plot(torque[::step], np.asarray(columns["encoder_arcsec"])[::step] / ARCSEC_PER_ARCMIN,
                lw=0.8, color="#bbbbbb", label=t("report.raw_encoder"))
    if "angle_arcsec" in columns:
        ax.plot(torque[::step], np.asarray(columns["angle_arcsec"])[::step] / ARCSEC_PER_ARCMIN,
                lw=1.0, color="#1f5fa8", label=t("report.compensated"))
    ax.set_xlabel(t("report.axis_torque"))
    ax.set_ylabel(t("report.axis_angle"))
    ax.axhline(0, color="#888", lw=0.5)
    ax.axvline(0, color="#888", lw=0.5)
    ax.grid(alpha=0.3)
    if len(torque):
        ax.legend(loc="upper left")
    else:
        ax.text(0.5, 0.5, t("report.no_samples"), ha="center", va="center", transform=ax.transAxes)
    fig.tight_layout()
    buf = io.StringIO()
    fig.savefig(buf, format="svg")
    svg = buf.getvalue()
    return svg[svg.find("<svg"):]


def _fmt(value: Any, lang: str = "en") -> str:
    if isinstance(value, bool):
        return text("verdict.pass", lang) if value else text("res.fail", lang)
    if isinstance(value, float):
        return f"{value:.6g}"
    return html.escape(str(value))


def flatten_results(results: Mapping[str, Any], prefix: str = "") -> list[tuple[str, Any]]:
    """Scalar entries of a (nested) results dict as (dotted key, value); lists of loops are summarised."""
    rows: list[tuple[str, Any]] = []
    for key, value in results.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            rows.extend(flatten_results(value, prefix=f"{name}."))
        elif isinstance(value, list | tuple):
            if value and all(isinstance(v, int | float) and not isinstance(v, bool) for v in value):
                rows.append((name, ", ".join(_fmt(float(v)) for v in value)))
            else:
                rows.append((name, f"{len(value)} entries"))
        else:
            rows.append((name, value))
    return rows


def loops_per_stage(columns: Mapping[str, np.ndarray], results: Mapping[str, Any] | None
                    ) -> Mapping[str, np.ndarray]:
    """For a test at several positions: only the samples of its evaluated loops, each stage's angles referred to
    the mean angle of its loops, so the loops of all positions overlay in one plot (the output's position would
    put them degrees apart). Other runs: the columns as they are."""
    loops = (results or {}).get("loops") or []
    if not (results or {}).get("positions") or "time_s" not in columns:
        return columns
    time_s = np.asarray(columns["time_s"])
    keep = np.zeros(time_s.size, dtype=bool)
    shift = {k: np.zeros(time_s.size) for k in ("angle_arcsec", "encoder_arcsec") if k in columns}
    for stage in sorted({lp.get("stage") for lp in loops if lp.get("evaluated")}):
        mask = evaluated_mask(time_s, [lp for lp in loops if lp.get("stage") == stage])
        keep |= mask
        for key in shift:
            if mask.any():
                shift[key][mask] = float(np.mean(np.asarray(columns[key])[mask]))
    out = {k: np.asarray(v)[keep] for k, v in columns.items()}
    for key, offset in shift.items():
        out[key] = out[key] - offset[keep]
    return out


def render_report(record: StoredRun, columns: Mapping[str, np.ndarray], lang: str = "en") -> str:
    """The report in ``lang`` (``en``, ``zh``; English for another)."""
    def t(key: str, **fields: Any) -> str:
        return text(key, lang, **fields)

    req = record.request
    plan = req.get("plan") if isinstance(req.get("plan"), Mapping) else None
    meta_rows = [
        (t("report.run"), record.id),
        (t("report.status"), t(f"state.{record.status}")),
        (t("report.reducer"), req.get("reducer")),
        (t("report.serial"), req.get("serial_number", "—")),
        (t("report.operator"), req.get("operator", "—")),
        *([(t("report.user"), req["user"])] if req.get("user") else []),
        *([(t("report.plan"), f"{plan.get('name')} v{plan.get('version')}")] if plan else []),
        (t("report.profile"), t(f"dash.{req['profile']}") if req.get("profile") in ("continuous", "stepped")
         else req.get("profile")),
        (t("report.torque"), req.get("max_torque_nm")),
        (t("report.cycles"), req.get("cycles")),
        (t("report.rate"), req.get("rate_nm_per_s", "—")),
        *([(t("report.positions"), req["positions"])] if req.get("positions") is not None else []),
        *([(t("report.rates"), req["rates"])] if req.get("rates") is not None else []),
        (t("report.samples"), record.sample_count),
        (t("report.created"), record.summary()["created_at"]),
        (t("report.finished"), record.summary()["finished_at"] or "—"),
    ]
    if record.error:
        meta_rows.append((t("report.error"), record.error))
    meta = "\n".join(f"<tr><th>{html.escape(k)}</th><td>{_fmt(v, lang)}</td></tr>" for k, v in meta_rows)
    results = _results_html(record.results, lang) if record.results else f"<p>{html.escape(t('report.no_results'))}</p>"
    html_lang = "zh-CN" if lang == "zh" else "en"
    return f"""<!doctype html>
<html lang="{html_lang}"><head><meta charset="utf-8"><title>{html.escape(t("report.title", id=record.id))}</title>
<style>
body {{ font-family: system-ui, "Noto Sans CJK SC", "Microsoft YaHei", sans-serif; margin: 2em; color: #222; }}
th {{ white-space: nowrap; }}
table {{ border-collapse: collapse; margin-bottom: 1.5em; }}
th, td {{ text-align: left; padding: 2px 12px 2px 0; border-bottom: 1px solid #eee; font-weight: normal; }}
th {{ color: #555; }} .loops th, .loops td {{ padding-right: 18px; }}
tr.pass td {{ color: #157a2e; font-weight: bold; }} tr.fail td {{ color: #b3261e; font-weight: bold; }}
tr.undecided td {{ color: #a15c00; font-weight: bold; }} .muted {{ color: #777; }}
</style></head><body>
<h1>{html.escape(t("report.title", id=record.id))}</h1>
<table class="meta">{meta}</table>
<h2>{html.escape(t("report.curve"))}</h2>
<figure>{hysteresis_svg(loops_per_stage(columns, record.results), lang)}</figure>
<h2>{html.escape(t("report.results"))}</h2>
{results}
</body></html>
"""


UNCERTAIN = ("rigidity_nm_per_arcmin", "lost_motion_arcsec", "backlash_arcsec", "k1_nm_per_rad", "k2_nm_per_rad",
             "k3_nm_per_rad")
HEADLINE: tuple[tuple[str, str], ...] = (  # (result key, catalogue key of its label or the label itself)
    ("rigidity_nm_per_arcmin", "report.rigidity"),
    ("lost_motion_arcsec", "report.lost_motion"),
    ("backlash_arcsec", "report.backlash"),
    ("loading_rate_nm_per_s", "report.loading_rate"),
    ("test_torque_nm", "report.test_torque"),
    ("n_loops", "report.n_loops"),
    ("k1_nm_per_rad", "K1 / N·m/rad"),
    ("k2_nm_per_rad", "K2 / N·m/rad"),
    ("k3_nm_per_rad", "K3 / N·m/rad"),
)


def _label(key: str, lang: str) -> str:
    return text(key, lang) if key.startswith("report.") else key


def _decision(entry: Mapping[str, Any]) -> str:
    """A verdict's or check's ISO 14253-1 decision (older runs have only ``passed``; neither: fail)."""
    return decision_of(entry) or "fail"


STAGE_COLUMNS = (("rigidity_nm_per_arcmin", "res.rigidity_short"), ("lost_motion_arcsec", "res.lost_motion_short"),
                 ("backlash_arcsec", "res.backlash_short"))


def _with_uncertainty(entry: Mapping[str, Any], key: str) -> str:
    """A stage's result as 'value ± U (k = …)' (the shared rendering), or the value and 'U not stated'."""
    value = entry.get(key)
    if not isinstance(value, int | float):
        return "–"
    return html.escape(with_uncertainty(float(value), (entry.get("uncertainty") or {}).get(key), unit=""))


def _stages_html(results: Mapping[str, Any], lang: str = "en") -> str:
    """The per-position or per-rate table of a test of several stages, its summary (max, min, spread; GB/T 40731)
    and, for rates, the rate sensitivity; '' for a single test."""
    entries = results.get("positions") or results.get("rates")
    if not isinstance(entries, list) or not entries:
        return ""
    positional = "positions" in results
    first = text("report.position" if positional else "report.loading_rate", lang)
    head = f"<tr><th>{html.escape(first)}</th>" + "".join(f"<th>{html.escape(text(label, lang))}</th>"
                                                         for _, label in STAGE_COLUMNS) + "</tr>"
    body = "".join(
        f"<tr><td>{_fmt(e.get('position_deg' if positional else 'rate_nm_per_s'))}</td>"
        + "".join(f"<td>{_with_uncertainty(e, key)}</td>" for key, _ in STAGE_COLUMNS) + "</tr>"
        for e in entries if isinstance(e, Mapping))
    for stat in ("max", "min", "spread"):
        body += f"<tr><th>{html.escape(text(f'res.{stat}', lang))}</th>" + "".join(f"<td>{_fmt(results.get(f'{key}_{stat}'))}</td>"
                                                 for key, _ in STAGE_COLUMNS) + "</tr>"
    sensitivity = results.get("rate_sensitivity")
    if isinstance(sensitivity, Mapping):
        body += f"<tr><th>{html.escape(text('report.per_decade', lang))}</th>" + "".join(
            f"<td>{_fmt(sensitivity.get(f'{key}_per_decade'))}</td>" for key, _ in STAGE_COLUMNS) + "</tr>"
    title = html.escape(text("report.positions_title" if positional else "report.rates_title", lang))
    return f"<h3>{title}</h3><table class='stages'>{head}{body}</table>"


def _results_html(results: Mapping[str, Any], lang: str = "en") -> str:
    """Headline values (value ± U with the dominant contributor, and the std over loops), the verdict checks
    with their ISO 14253-1 decision, the per-loop table, the warnings, then every value."""
    def t(key: str, **fields: Any) -> str:
        return text(key, lang, **fields)

    parts = []
    std = results.get("std") or {}
    uncertainty = results.get("uncertainty") or {}
    rows = []
    for key, label in HEADLINE:
        value = results.get(key)
        if isinstance(value, int | float) and not isinstance(value, bool):
            entry = uncertainty.get(key) if isinstance(uncertainty, Mapping) else None
            spread = std.get(key) if isinstance(std, Mapping) else None
            if key in UNCERTAIN:
                shown = with_uncertainty(float(value), entry, "")
                if not isinstance(entry, Mapping):
                    shown = shown.replace(NOT_STATED, t("res.u_not_stated"))
                dominant = (t("report.dominant", name=source_text(entry.get("dominant"), lang))
                            if isinstance(entry, Mapping) else "")
            else:
                shown, dominant = _fmt(float(value)), ""
            scatter = t("report.std", value=f"{float(spread):.2g}") if isinstance(spread, int | float) else ""
            rows.append(f"<tr><th>{html.escape(_label(label, lang))}</th><td>{html.escape(shown)}</td>"
                        f"<td class='muted'>{html.escape(dominant)}</td><td class='muted'>{scatter}</td></tr>")
    if rows:
        basis = results.get("uncertainty_basis")
        parts.append("<table class='results'>" + "".join(rows) + "</table>")
        parts.append(f"<p class='muted'>{html.escape(t('report.u_note', basis=source_text(basis or NOT_STATED, lang)))}</p>")
    verdict = results.get("verdict")
    if isinstance(verdict, Mapping):
        rows = []
        for check in (verdict.get("checks") or {}).values():
            decision = _decision(check)
            guard = check.get("guard_band")
            guard_text = (" " + t("report.guard_band", value=_fmt(float(guard)))
                          if isinstance(guard, int | float) and guard else "")
            rows.append(
                f"<tr class='{decision}'><th>{html.escape(check_label(check, lang))}</th>"
                f"<td>{_fmt(check.get('value'), lang)}{html.escape(guard_text)}</td>"
                f"<td>{html.escape(t(f'verdict.{decision}'))}</td></tr>"
            )
        decision = _decision(verdict)
        rule = verdict.get("rule")
        rule_words = t("report.rule", rule=rule_text(rule, lang)) if rule else ""
        rows.append(f"<tr class='{decision}'><th>{html.escape(t('report.decision'))}</th><td>{html.escape(rule_words)}"
                    f"</td><td>{html.escape(t(f'res.{decision}'))}</td></tr>")
        for reason in reasons_text(verdict, lang):
            rows.append(f"<tr class='undecided'><th></th><td colspan='2'>{html.escape(reason)}</td></tr>")
        parts.append(f"<h3>{html.escape(t('report.acceptance'))}</h3><table class='verdict'>" + "".join(rows) + "</table>")
    parts.append(_stages_html(results, lang))
    loops = results.get("loops")
    if isinstance(loops, list) and loops and all(isinstance(lp, Mapping) for lp in loops):
        cols = ("index", "evaluated", "order", "rigidity_nm_per_arcmin", "backlash_arcsec", "lost_motion_arcsec",
                "loading_rate_nm_per_s")
        head = "".join(f"<th>{c}</th>" for c in cols)
        body = "".join(
            "<tr>" + "".join(f"<td>{t('report.yes') if lp.get(c) is True else t('report.no') if lp.get(c) is False else _fmt(lp.get(c))}</td>"
                             for c in cols) + "</tr>"
            for lp in loops
        )
        parts.append(f"<h3>{html.escape(t('report.loops'))}</h3><table class='loops'><tr>{head}</tr>{body}</table>")
    warnings = warnings_text(results, lang) if isinstance(results.get("warnings"), list) else []
    if warnings:
        parts.append(f"<h3>{html.escape(t('report.warnings'))}</h3><ul>" + "".join(f"<li>{html.escape(w)}</li>" for w in warnings) + "</ul>")
    details = "".join(
        f"<tr><th>{html.escape(k)}</th><td>{_fmt(v)}</td></tr>" for k, v in flatten_results(results)
    )
    parts.append(f"<details><summary>{html.escape(t('report.all_values'))}</summary><table class='details'>{details}"
                 "</table></details>")
    return "\n".join(parts)

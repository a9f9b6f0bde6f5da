"""HTML report of a discrepancy run: tables and matplotlib plots (PNG embedded, no external files)."""

from __future__ import annotations

import base64
import html
import io
from typing import Any

import numpy as np

from tcms_daq.discrepancy.catalogue import CATALOGUE


def _png(fig) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90, bbox_inches="tight")
    import matplotlib.pyplot as plt

    plt.close(fig)
    return base64.b64encode(buf.getvalue()).decode("ascii")


def _thin(n: int, limit: int = 20000) -> np.ndarray:
    return np.arange(0, n, max(1, n // limit))


def figures(result) -> list[tuple[str, str]]:
    """(caption, base64 PNG) of the report's plots."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    d = result.data
    before, after = result.residual_before_arcsec, result.residual_after_arcsec
    i = _thin(len(before))
    out: list[tuple[str, str]] = []
    kw_b: dict[str, Any] = {"s": 3, "alpha": 0.5, "color": "tab:red", "label": "before (measured − simulated)"}
    kw_a: dict[str, Any] = {"s": 3, "alpha": 0.5, "color": "tab:blue", "label": "after (measured − re-simulated)"}

    x_time = d.time_s if d.has_time else np.arange(len(before))
    fig, ax = plt.subplots(figsize=(9, 3.2))
    ax.scatter(x_time[i], before[i], **kw_b)
    ax.scatter(x_time[i], after[i], **kw_a)
    ax.set_xlabel("time [s]" if d.has_time else "sample")
    ax.set_ylabel("residual [″]")
    ax.axhline(0, color="k", lw=0.5)
    ax.legend(loc="best", fontsize=8, markerscale=3)
    out.append(("Residual against time, before and after adding the named effects", _png(fig)))

    fig, axes = plt.subplots(1, 2, figsize=(11, 3.6), sharey=True)
    for ax, r, title in ((axes[0], before, "before"), (axes[1], after, "after")):
        up = d.direction[i] > 0
        ax.scatter(d.torque_nm[i][up], r[i][up], s=3, alpha=0.5, color="tab:orange", label="loading")
        ax.scatter(d.torque_nm[i][~up], r[i][~up], s=3, alpha=0.5, color="tab:green", label="unloading")
        ax.set_title(f"residual {title}")
        ax.set_xlabel("torque [N·m]")
        ax.axhline(0, color="k", lw=0.5)
    axes[0].set_ylabel("residual [″]")
    axes[0].legend(fontsize=8, markerscale=3)
    out.append(("Residual against torque by load direction (a direction-odd part separates the colours)", _png(fig)))

    fig, ax = plt.subplots(figsize=(9, 3.2))
    ax.scatter(d.sim_angle_arcsec[i], before[i], **kw_b)
    ax.scatter(d.sim_angle_arcsec[i], after[i], **kw_a)
    ax.set_xlabel("simulated angle [″]")
    ax.set_ylabel("residual [″]")
    ax.axhline(0, color="k", lw=0.5)
    ax.legend(fontsize=8, markerscale=3)
    out.append(("Residual against angle (encoder-periodic errors show up here)", _png(fig)))

    fig, ax = plt.subplots(figsize=(7, 5))
    ax.plot(d.torque_nm[i], d.measured_angle_arcsec[i], ".", ms=2, color="k", label="measured")
    ax.plot(d.torque_nm[i], d.sim_angle_arcsec[i], "-", lw=0.8, color="tab:red", label="simulated")
    ax.plot(d.torque_nm[i], result.resimulated_angle_arcsec[i], "-", lw=0.8, color="tab:blue",
            label="re-simulated with the named effects")
    ax.set_xlabel("torque [N·m]")
    ax.set_ylabel("angle [″]")
    ax.legend(fontsize=8)
    out.append(("The loops: measured, simulated and re-simulated torque–angle curves", _png(fig)))

    path = [result.cv_rms_before_arcsec] + [e.cv_rms_after_arcsec for e in result.effects]
    labels = ["offset only"] + [f"+ {e.name}" for e in result.effects]
    fig, ax = plt.subplots(figsize=(7, 3))
    ax.bar(range(len(path)), path, color="tab:gray")
    ax.axhline(result.cv_rms_after_arcsec, color="tab:blue", ls="--", lw=1,
               label=f"nested CV after the workflow {result.cv_rms_after_arcsec:.3f}″")
    ax.set_xticks(range(len(path)), labels, rotation=20, fontsize=8)
    ax.set_ylabel("held-out RMS [″]")
    ax.legend(fontsize=8)
    out.append(("The gap shrinking: blocked cross-validated RMS as effects are added", _png(fig)))

    pg = result.localisation.get("periodogram_angle")
    if pg:
        fig, ax = plt.subplots(figsize=(7, 3))
        ax.semilogx(pg["period_arcsec"], pg["amplitude_arcsec"], color="tab:red")
        ax.axvline(result.signal_period_arcsec, color="k", ls=":", lw=1, label="signal period")
        ax.axvline(result.signal_period_arcsec / 2, color="k", ls="--", lw=0.8, label="half signal period")
        ax.set_xlabel("period in angle [″]")
        ax.set_ylabel("amplitude [″]")
        ax.legend(fontsize=8)
        out.append(("Periodogram of the residual (before) in the angle", _png(fig)))
    return out


def _table(rows: list[list[str]], head: list[str]) -> str:
    h = "".join(f"<th>{html.escape(c)}</th>" for c in head)
    body = "".join("<tr>" + "".join(f"<td>{c}</td>" for c in r) + "</tr>" for r in rows)
    return f"<table><tr>{h}</tr>{body}</table>"


def _fmt(v: float) -> str:
    return f"{v:.4g}"


def render_html(result, *, title: str = "Discrepancy report") -> str:
    """The complete report as one HTML document."""
    r = result
    summary = _table([
        ["RMS [″]", _fmt(r.rms_before_arcsec), _fmt(r.rms_after_arcsec)],
        ["max |residual| [″]", _fmt(r.max_before_arcsec), _fmt(r.max_after_arcsec)],
        ["held-out RMS [″] (blocked CV; after: nested)", _fmt(r.cv_rms_before_arcsec), _fmt(r.cv_rms_after_arcsec)],
    ] + [[f"RMS {k} [″]", _fmt(v["rms_before_arcsec"]), _fmt(v["rms_after_arcsec"])]
         for k, v in r.per_direction.items()], ["", "before", "after"])
    if r.effects:
        eff = _table([[html.escape(e.name), html.escape(CATALOGUE[e.name].description),
                       ", ".join(f"{k} = {_fmt(v)}" for k, v in e.parameters.items()),
                       _fmt(e.cv_rms_before_arcsec), _fmt(e.cv_rms_after_arcsec), f"{e.inclusion:.0%}"]
                      for e in r.effects],
                     ["effect", "meaning", "parameters", "CV RMS before [″]", "CV RMS after [″]",
                      "selected in outer folds"])
    else:
        eff = "<p><b>No effect named.</b> No catalogue term improved the held-out error reliably.</p>"
    alias = ""
    if r.aliases:
        alias = "<h2>Look-alikes the data cannot tell apart</h2>" + _table(
            [[html.escape(", ".join(a.names)), "yes (as " + html.escape(a.representative) + ")" if a.in_model else "no",
              html.escape(a.separating_experiment)] for a in r.aliases],
            ["effects", "in the model", "experiment that would separate them"])
    rej = ""
    if r.rejected or r.unavailable:
        rows = [[html.escape(x["name"]), "rejected", html.escape(x["reason"])] for x in r.rejected]
        rows += [[html.escape(k), "not a candidate", html.escape(v)] for k, v in r.unavailable.items()]
        rej = "<h2>Not named</h2>" + _table(rows, ["effect", "", "why"])
    loc = r.localisation.get("against", {})
    loc_rows = [[html.escape(k), f"{v['explained_fraction']:.0%}"] for k, v in loc.items()]
    parts = r.localisation.get("direction_parts", {})
    if parts.get("even_rms_arcsec") is not None:
        loc_rows.append(["direction-even part RMS [″]", _fmt(parts["even_rms_arcsec"])])
        loc_rows.append(["direction-odd part RMS [″]", _fmt(parts["odd_rms_arcsec"])])
    pg = r.localisation.get("periodogram_angle")
    if pg:
        loc_rows.append(["periodogram peak in angle", f"{_fmt(pg['peak_amplitude_arcsec'])}″ at "
                                                       f"{_fmt(pg['peak_period_arcsec'])}″"])
    local = _table(loc_rows, ["residual before against", "share of variance in bin means / value"])
    figs = "".join(f"<figure><img src='data:image/png;base64,{b64}' alt='{html.escape(cap)}'>"
                   f"<figcaption>{html.escape(cap)}</figcaption></figure>" for cap, b64 in figures(r))
    groups = r.groups
    return f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>{html.escape(title)}</title>
<style>
body{{font-family:system-ui,sans-serif;max-width:1100px;margin:1em auto;padding:0 1em;color:#222}}
table{{border-collapse:collapse;margin:.5em 0 1em}} td,th{{border:1px solid #ccc;padding:3px 8px;text-align:left}}
th{{background:#f3f3f3}} figure{{margin:1em 0}} figcaption{{font-size:.9em;color:#555}} img{{max-width:100%}}
</style></head><body>
<h1>{html.escape(title)}</h1>
<p>Residual = measured − simulated angle. A constant offset ({_fmt(r.offset_arcsec)}″) is always fitted and is not an
effect. Held-out errors are cross-validated over {groups['count']} {html.escape(groups['kind'])} (each left out in
turn); the error after the workflow repeats the whole selection inside every outer fold (nested), so it is honest.</p>
<h2>Verdict: {html.escape(r.verdict.verdict.replace("_", " "))}</h2>
<p class="verdict">{html.escape(r.verdict.words())}</p>{_remainder_table(r)}
<h2>Before and after</h2>{summary}
<h2>Named effects{" (provisional: structure remains that they do not explain)" if r.verdict.provisional and r.effects else ""}</h2>{eff}{alias}{rej}
<h2>Where the residual lives (before)</h2>{local}
<h2>Plots</h2>{figs}
</body></html>
"""


def _remainder_table(r) -> str:
    """Where the structure that remains is (the verdict's ``unexplained`` block), as a table."""
    v = r.verdict
    rows = [["noise floor [″] (from the residual's second differences)", _fmt(v.noise_floor_arcsec)],
            ["structure removed by the named effects", f"{v.removed_share:.0%}"]]
    rest = v.unexplained
    if rest is not None:
        rows.append(["remaining structure RMS [″]", _fmt(rest["structured_rms_arcsec"])])
        rows.append(["its shape", html.escape(rest["shape"].replace("_", " "))])
        for s in rest["spans"]:
            where = (f"{_fmt(s['from_s_after_start'])}…{_fmt(s['to_s_after_start'])} s after the start"
                     if s.get("from_s_after_start") is not None
                     else f"samples {s['from_sample']:.0f}…{s['to_sample']:.0f}")
            lo, hi = s["torque_range_nm"]
            rows.append(["visible", f"{where}, torque {_fmt(lo)}…{_fmt(hi)} N·m, loading share "
                                    f"{s['loading_share']:.0%}, mean {_fmt(s['mean_arcsec'])}″"])
    return _table(rows, ["what remains", ""])


def parameters_text(parameters: dict[str, float], expanded: dict[str, float], k: float | None) -> str:
    """"name=value ± U" per parameter (U = k·u, about 95 %; k said at the end), "name=value" without U."""
    parts = [f"{key}={v:.4g}" + (f" ± {expanded[key]:#.2g}" if key in expanded else "") for key, v in parameters.items()]
    return ", ".join(parts) + (f"; ± U, k = {k:.2f}, about 95 %" if expanded and k is not None else "")


def format_text(result) -> str:
    """The result as plain text lines: the verdict, named effects, aliases, rejected candidates, RMS before →
    after."""
    lines = [f"verdict: {result.verdict.verdict} — {result.verdict.words()}"]
    if result.pairing is not None and result.pairing.mode != "same_rows":
        how = result.pairing
        offset = f", simulated clock offset {how.time_offset_s:+.4g} s" if how.time_offset_s is not None else ""
        lines.append(f"pairing: the simulation put onto the measured rows ({how.mode.replace('_', ' ')}{offset}); "
                     f"{how.rows_used} of {how.rows_measured} measured rows compared")
    if result.pairing is not None and result.pairing.block_samples > 1:
        how = result.pairing
        lines.append(f"averaged: {how.rows_used} rows in blocks of {how.block_samples} consecutive samples "
                     f"({how.rows_analysed} analysed rows; none across a reversal or a gap)")
    if result.effects:
        label = "named (provisional)" if result.verdict.provisional else "named"
        for e in result.effects:
            params = parameters_text(e.parameters, e.expanded_uncertainty, e.coverage_factor)
            lines.append(f"{label}: {e.name} ({params}); held-out RMS {e.cv_rms_before_arcsec:.3f}″ → "
                         f"{e.cv_rms_after_arcsec:.3f}″")
    else:
        lines.append("named: nothing (no catalogue effect improves the held-out error reliably)")
    for a in result.aliases:
        kept = ""
        if a.in_model:
            params = ", ".join(f"{k}={v:.4g}" for k, v in a.parameters.items())
            kept = f" (in the model as {a.representative}: {params})"
        lines.append(f"aliases: {', '.join(a.names)} cannot be told apart here{kept} — {a.separating_experiment}")
    for r in result.rejected:
        lines.append(f"rejected: {r['name']}: {r['reason']}")
    lines.append(f"RMS {result.rms_before_arcsec:.3f}″ → {result.rms_after_arcsec:.3f}″, max "
                 f"{result.max_before_arcsec:.3f}″ → {result.max_after_arcsec:.3f}″, held-out RMS "
                 f"{result.cv_rms_before_arcsec:.3f}″ → {result.cv_rms_after_arcsec:.3f}″ (nested CV over "
                 f"{result.groups['count']} {result.groups['kind']})")
    return "\n".join(lines)

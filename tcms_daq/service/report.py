"""The HTML report of one run: request, outcome, the hysteresis plot (inline SVG) and the results table."""

from __future__ import annotations

import html
import io
from collections.abc import Mapping
from typing import Any

import numpy as np

from tcms_daq.store import RunRecord
from tcms_daq.units import ARCSEC_PER_ARCMIN

MAX_PLOT_POINTS = 20_000


def hysteresis_svg(columns: Mapping[str, np.ndarray]) -> str:
    """Angle (arcmin) against torque (N·m), compensated and raw; decimated to at most MAX_PLOT_POINTS."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.figure import Figure

    torque = np.asarray(columns.get("torque_nm", np.empty(0)))
    step = max(1, len(torque) // MAX_PLOT_POINTS)
    fig = Figure(figsize=(7.0, 4.6))
    ax = fig.add_subplot()
    if "encoder_arcsec" in columns:
        ax.plot(torque[::step], np.asarray(columns["encoder_arcsec"])[::step] / ARCSEC_PER_ARCMIN,
                lw=0.8, color="#bbbbbb", label="raw encoder")
    if "angle_arcsec" in columns:
        ax.plot(torque[::step], np.asarray(columns["angle_arcsec"])[::step] / ARCSEC_PER_ARCMIN,
                lw=1.0, color="#1f5fa8", label="compensated")
    ax.set_xlabel("torque / N·m")
    ax.set_ylabel("twist angle / arcmin")
    ax.axhline(0, color="#888", lw=0.5)
    ax.axvline(0, color="#888", lw=0.5)
    ax.grid(alpha=0.3)
    if len(torque):
        ax.legend(loc="upper left")
    else:
        ax.text(0.5, 0.5, "no samples recorded", ha="center", va="center", transform=ax.transAxes)
    fig.tight_layout()
    buf = io.StringIO()
    fig.savefig(buf, format="svg")
    svg = buf.getvalue()
    return svg[svg.find("<svg"):]


def _fmt(value: Any) -> str:
    if isinstance(value, bool):
        return "pass" if value else "FAIL"
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


def render_report(record: RunRecord, columns: Mapping[str, np.ndarray]) -> str:
    req = record.request
    meta_rows = [
        ("run", record.id),
        ("status", record.status),
        ("reducer", req.get("reducer")),
        ("serial number", req.get("serial_number", "—")),
        ("operator", req.get("operator", "—")),
        ("profile", req.get("profile")),
        ("test torque / N·m", req.get("max_torque_nm")),
        ("cycles", req.get("cycles")),
        ("torque rate / N·m/s", req.get("rate_nm_per_s", "—")),
        ("samples", record.sample_count),
        ("created", record.summary()["created_at"]),
        ("finished", record.summary()["finished_at"] or "—"),
    ]
    if record.error:
        meta_rows.append(("error", record.error))
    meta = "\n".join(f"<tr><th>{html.escape(k)}</th><td>{_fmt(v)}</td></tr>" for k, v in meta_rows)
    if record.results:
        result_rows = "\n".join(
            f'<tr class="{_row_class(k, v)}"><th>{html.escape(k)}</th><td>{_fmt(v)}</td></tr>'
            for k, v in flatten_results(record.results)
        )
        results = f"<table class='results'>{result_rows}</table>"
    else:
        results = "<p>No results (the run did not complete an evaluation).</p>"
    return f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>TCMS report {html.escape(record.id)}</title>
<style>
body {{ font-family: system-ui, sans-serif; margin: 2em; color: #222; }}
table {{ border-collapse: collapse; margin-bottom: 1.5em; }}
th, td {{ text-align: left; padding: 2px 12px 2px 0; border-bottom: 1px solid #eee; font-weight: normal; }}
th {{ color: #555; }}
tr.pass td {{ color: #157a2e; font-weight: bold; }} tr.fail td {{ color: #b3261e; font-weight: bold; }}
</style></head><body>
<h1>Torsional characteristic test {html.escape(record.id)}</h1>
<table class="meta">{meta}</table>
<h2>Hysteresis curve</h2>
<figure>{hysteresis_svg(columns)}</figure>
<h2>Results</h2>
{results}
</body></html>
"""


def _row_class(key: str, value: Any) -> str:
    if isinstance(value, bool):
        return "pass" if value else "fail"
    return ""

"""The certificate's figure of a turning test (docs/transmission.md), from what the dashboard draws too
(:func:`tcms_daq.service.method_views.method_curves`):

- transmission error: the TE against the output angle per direction (measured, trend and mean removed, and the sum
  of the lines found) above its amplitude spectrum by order, each line found marked with its order and component;
- starting torque: each ramp's input torque against the time from its fitted breakaway, the starting torques
  marked, above the input angle (the breakaway);
- no-load torque: the no-load torque and each direction's torque against the input speed, with their U;
- efficiency: each direction's blocks of whole input revolutions with the mean ± U as a band.

Every label comes from the caller (the certificate's catalogue); the figure is SVG text with its glyphs as paths.
"""

from __future__ import annotations

import io
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from tcms_daq.service.method_views import method_curves

Label = Callable[..., str]
COLOUR = {"forward": "#1f5fa8", "reverse": "#d9771e"}
FIT = {"forward": "#0b2f5a", "reverse": "#7a3c05"}
SHADES = {"forward": ("#1f5fa8", "#4f86c6", "#86aedb"), "reverse": ("#d9771e", "#e89a52", "#f2bd8a")}
LINE = "#b3261e"


def component_words(name: Any, label: Label) -> str:
    """A line's component in the catalogue's words (``pin_ring 2×`` → "pin ring 2×"; several joined by " / ");
    the catalogue's "no component" for None."""
    if not name:
        return label("no_component")
    words = []
    for part in str(name).split(" / "):
        twice = part.endswith(" 2×")
        base = part[:-3] if twice else part
        try:
            word = label(f"component_{base}")
        except KeyError:
            word = base.replace("_", " ")
        words.append(word + (" 2×" if twice else ""))
    return " / ".join(words)


def _te(fig: Any, curves: Mapping[str, Any], label: Label) -> None:
    top, bottom = fig.subplots(2, 1, gridspec_kw={"height_ratios": (1.0, 1.0)})
    curve, spectrum = curves.get("te_curve") or {}, curves.get("te_spectrum") or {}
    for d in ("forward", "reverse"):
        c = curve.get(d)
        if isinstance(c, Mapping):
            direction = label(f"direction_{d}")
            top.plot(c["output_angle_deg"], c["te_arcsec"], lw=0.6, color=COLOUR[d],
                     label=label("legend_te_measured", direction=direction))
            top.plot(c["output_angle_deg"], c["te_fit_arcsec"], lw=0.9, ls="--", color=FIT[d],
                     label=label("legend_te_lines", direction=direction))
    top.set_xlabel(label("axis_output_angle"))
    top.set_ylabel(label("axis_te"))
    top.set_xlim(0, 360)
    top.set_xticks(np.arange(0, 361, 45))
    top.grid(alpha=0.3)
    low, high = top.get_ylim()
    top.set_ylim(low, high + 0.3 * (high - low))  # a band above the curves for the legend: it hid their peaks
    top.legend(loc="upper left", fontsize=6.5, ncol=2, framealpha=0.9)
    for d in ("forward", "reverse"):
        s = spectrum.get(d)
        if isinstance(s, Mapping) and len(s.get("order") or []):
            bottom.vlines(s["order"], 0.0, s["amplitude_arcsec"], color=COLOUR[d], lw=0.9, alpha=0.8,
                          label=label(f"direction_{d}"))
    lines = [ln for ln in curves.get("te_lines") or [] if isinstance(ln.get("amplitude_arcsec"), int | float)]
    if lines:
        bottom.plot([ln["order"] for ln in lines], [ln["amplitude_arcsec"] for ln in lines], ls="none", marker="o",
                    ms=3.5, color=LINE, zorder=4)
        biggest = max(ln["amplitude_arcsec"] for ln in lines)
        placed: list[tuple[float, float]] = []  # (log10 order, height) of the labels written
        for ln in sorted(lines, key=lambda x: -x["amplitude_arcsec"]):
            x, y = float(ln["order"]), float(ln["amplitude_arcsec"])
            at = y + 0.06 * biggest
            while any(abs(np.log10(x) - px) < 0.35 and abs(at - py) < 0.09 * biggest for px, py in placed):
                at += 0.09 * biggest
            placed.append((float(np.log10(x)), at))
            bottom.annotate(f"{x:.4g} {component_words(ln.get('component'), label)}", (x, y), (x, at),
                            fontsize=6.5, ha="left", va="bottom",
                            arrowprops={"arrowstyle": "-", "lw": 0.4, "color": "#888"} if at - y > 0.07 * biggest
                            else None)
        bottom.set_ylim(0, 1.5 * biggest + 0.1 * biggest * len(lines) / 2)
    bottom.set_xscale("log")
    from matplotlib.ticker import FuncFormatter

    bottom.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    bottom.set_xlabel(label("axis_order"))
    bottom.set_ylabel(label("axis_te_amplitude"))
    bottom.grid(alpha=0.3, which="both")
    bottom.legend(loc="upper right", fontsize=6.5, framealpha=0.9)


def _ramp_names(ramps: list[Mapping[str, Any]], label: Label) -> list[tuple[str, str]]:
    seen: dict[str, int] = {}
    out = []
    for r in ramps:
        d = str(r.get("direction"))
        seen[d] = seen.get(d, 0) + 1
        shades = SHADES.get(d, ("#5b6678",))
        out.append((label("legend_ramp", direction=label(f"direction_{d}") if d in COLOUR else d, n=seen[d]),
                    shades[(seen[d] - 1) % len(shades)]))
    return out


def _starting(fig: Any, curves: Mapping[str, Any], label: Label) -> None:
    top, bottom = fig.subplots(2, 1, sharex=True, gridspec_kw={"height_ratios": (1.4, 1.0)})
    ramps = [r for r in curves.get("ramps") or [] if isinstance(r, Mapping)]
    names = _ramp_names(ramps, label)
    for r, (name, colour) in zip(ramps, names, strict=True):
        top.plot(r["time_from_onset_s"], r["input_torque_nm"], lw=0.9, color=colour, label=name)
        bottom.plot(r["time_from_onset_s"], r["input_angle_arcsec"], lw=0.9, color=colour)
    marks = [(-1.0 if r.get("direction") == "reverse" else 1.0) * float(r["torque_nm"]) for r in ramps]
    if marks:
        top.plot(np.zeros(len(marks)), marks, ls="none", marker="o", ms=4, color=LINE,
                 label=label("legend_starting_torque"), zorder=4)
    top.axvline(0.0, color="#888", lw=0.5)
    bottom.axvline(0.0, color="#888", lw=0.5)
    top.set_ylabel(label("axis_input_torque"))
    bottom.set_ylabel(label("axis_input_angle"))
    bottom.set_xlabel(label("axis_time_from_onset"))
    for ax in (top, bottom):
        ax.grid(alpha=0.3)
    handles, names = top.get_legend_handles_labels()  # in the angle's panel, empty before the breakaway
    bottom.legend(handles, names, loc="upper left", fontsize=6.5, ncol=4, framealpha=0.9)


def _no_load(fig: Any, curves: Mapping[str, Any], label: Label) -> None:
    ax = fig.subplots()
    speeds = [s for s in curves.get("speeds") or [] if isinstance(s, Mapping)]
    for key, colour, style, name in (
            ("no_load", LINE, "-", label("legend_no_load")),
            ("forward", COLOUR["forward"], "--", label("legend_no_load_direction", direction=label("direction_forward"))),
            ("reverse", COLOUR["reverse"], "--", label("legend_no_load_direction", direction=label("direction_reverse")))):
        rows = [(s["speed_rpm"], s[key]["value"], s[key]["U"] or 0.0) for s in speeds
                if isinstance(s.get(key), Mapping) and isinstance(s[key].get("value"), int | float)]
        if rows:
            x, y, u = (np.asarray(v, dtype=float) for v in zip(*rows, strict=True))
            ax.errorbar(x, y, yerr=u, color=colour, ls=style, lw=1.0, marker="o", ms=4, capsize=3, label=name)
    ax.set_xlim(left=0)
    ax.set_ylim(bottom=0)
    ax.set_xlabel(label("axis_input_speed"))
    ax.set_ylabel(label("axis_no_load_torque"))
    ax.grid(alpha=0.3)
    ax.legend(loc="lower right", fontsize=7, framealpha=0.9)


def _efficiency(fig: Any, curves: Mapping[str, Any], label: Label, shown: Callable[[float, float | None], str]
                ) -> None:
    ax = fig.subplots()
    for d in curves.get("directions") or []:
        blocks = np.asarray(d.get("block_efficiencies") or [], dtype=float) * 100.0
        direction = str(d.get("direction"))
        colour = COLOUR.get(direction, "#5b6678")
        value, expanded = d.get("value"), d.get("U")
        if not blocks.size or not isinstance(value, int | float):
            continue
        x = np.arange(1, blocks.size + 1)
        ax.plot(x, blocks, lw=1.0, marker="o", ms=3, color=colour,
                label=label("legend_efficiency", direction=label(f"direction_{direction}"),
                            value=shown(100.0 * value, None if expanded is None else 100.0 * expanded)))
        if isinstance(expanded, int | float):
            ax.axhspan(100.0 * (value - expanded), 100.0 * (value + expanded), color=colour, alpha=0.15, lw=0)
        ax.axhline(100.0 * value, color=colour, lw=0.6, ls="--")
    ax.set_xlabel(label("axis_block"))
    ax.set_ylabel(label("axis_efficiency"))
    ax.grid(alpha=0.3)
    ax.legend(loc="best", fontsize=7, framealpha=0.9)


def method_figure_svg(results: Mapping[str, Any] | None, columns: Mapping[str, np.ndarray] | None, label: Label,
                      shown: Callable[[float, float | None], str] = lambda v, u: f"{v:.4g}") -> str | None:
    """The figure of a turning test as SVG text, or None for the stiffness test (its loop: ``loop_figure``).
    ``label(key, **fields)`` gives each text; ``shown(value, U)`` renders a value (in %) with its U for a legend."""
    curves = method_curves(results, columns)
    method = curves["method"]
    if method == "stiffness":
        return None
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.figure import Figure

    tall = method in ("transmission-error", "starting-torque")
    fig = Figure(figsize=(6.6, 6.4 if tall else 3.6))
    if method == "transmission-error":
        _te(fig, curves, label)
    elif method == "starting-torque":
        _starting(fig, curves, label)
    elif method == "no-load-torque":
        _no_load(fig, curves, label)
    else:
        _efficiency(fig, curves, label, shown)
    fig.tight_layout()
    buf = io.StringIO()
    fig.savefig(buf, format="svg")
    svg = buf.getvalue()
    return svg[svg.find("<svg"):]

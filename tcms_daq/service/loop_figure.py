"""The certificate's hysteresis figure: the evaluated loops in relative twist (arcmin, zero at the loop's centre,
the midline at zero torque) against torque, with the evaluation's lines drawn.

A single test shows its loops with the rigidity secant of each side (through the midline over the rigidity
interval), the lost-motion points at ± the lost-motion torque and the backlash at zero torque, all from the
evaluation's own numbers (``per_direction``, ``lost_motion_torque_nm``, ``backlash_arcsec``). A test at several
positions or rates overlays each stage's loops about its own centre (an output position is degrees away from
another) with the rigidity interval and the lost-motion torque marked. Every label comes from the caller (the
certificate's catalogue).
"""

from __future__ import annotations

import io
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from tcms_daq.units import ARCSEC_PER_ARCMIN

MAX_POINTS_PER_CURVE = 6000
CENTRE_BAND = 0.1  # samples within ±10 % of the largest torque fix the midline at zero torque
COLOURS = ("#1f5fa8", "#d9771e", "#2e8b57", "#8e44ad", "#b3261e", "#5b6678", "#c2185b", "#00838f", "#6d4c41",
           "#7cb342")
LINE = "#b3261e"

Label = Callable[..., str]


def loop_centre_arcsec(torque_nm: np.ndarray, angle_arcsec: np.ndarray) -> float:
    """The loop's centre: the midline at zero torque, the mean of both branches' angles at T = 0, each from a
    straight-line fit of its samples within ±CENTRE_BAND of the largest torque. Falls back to the mean angle of
    those samples when a branch has fewer than three of them (and to the mean of all when there are none)."""
    torque = np.asarray(torque_nm, dtype=float)
    angle = np.asarray(angle_arcsec, dtype=float)
    ok = np.isfinite(torque) & np.isfinite(angle)
    torque, angle = torque[ok], angle[ok]
    if not len(torque):
        return 0.0
    near = np.abs(torque) <= CENTRE_BAND * float(np.max(np.abs(torque)))
    if not near.any():
        return float(np.mean(angle))
    rising = np.gradient(torque) > 0 if len(torque) > 1 else np.zeros(len(torque), dtype=bool)
    at_zero = []
    for branch in (near & rising, near & ~rising):
        if np.count_nonzero(branch) >= 3 and np.ptp(torque[branch]) > 0:
            slope, intercept = np.polyfit(torque[branch], angle[branch], 1)
            at_zero.append(float(intercept))
    return float(np.mean(at_zero)) if len(at_zero) == 2 else float(np.mean(angle[near]))


def evaluated_mask(time_s: np.ndarray, loops: list[Mapping[str, Any]], stage: int | None = None) -> np.ndarray:
    """The samples inside the evaluated loops (of stage ``stage``; None: of every stage) by their time windows."""
    mask = np.zeros(time_s.size, dtype=bool)
    for lp in loops:
        if lp.get("evaluated") and (stage is None or lp.get("stage") == stage):
            mask |= (time_s >= float(lp["start_time_s"])) & (time_s <= float(lp["end_time_s"]))
    return mask


def relative_loops(columns: Mapping[str, np.ndarray], results: Mapping[str, Any] | None
                   ) -> list[tuple[int | None, np.ndarray, np.ndarray]]:
    """(stage, torque N·m, twist arcmin relative to the centre) of the evaluated loops, one entry per stage of a
    test at several positions or rates (stage numbers from 1), one entry (stage None) otherwise. A run without
    loop times (or with none evaluated) gives all its samples."""
    torque = np.asarray(columns.get("torque_nm", np.empty(0)), dtype=float)
    angle = np.asarray(columns.get("angle_arcsec", np.empty(0)), dtype=float)
    if not len(torque) or len(angle) != len(torque):
        return []
    time_s = np.asarray(columns.get("time_s", np.arange(len(torque))), dtype=float)
    loops = [lp for lp in (results or {}).get("loops") or [] if isinstance(lp, Mapping)
             and isinstance(lp.get("start_time_s"), int | float) and isinstance(lp.get("end_time_s"), int | float)]
    staged = bool((results or {}).get("positions") or (results or {}).get("rates"))
    numbered = sorted({int(lp["stage"]) for lp in loops if lp.get("evaluated") and isinstance(lp.get("stage"), int)})
    stages: list[int | None] = list(numbered) if staged and numbered else [None]
    out = []
    for stage in stages:
        mask = evaluated_mask(time_s, loops, stage) if loops else np.ones(len(torque), dtype=bool)
        if not mask.any():
            mask = np.ones(len(torque), dtype=bool)
        t, a = torque[mask], angle[mask]
        out.append((stage, t, (a - loop_centre_arcsec(t, a)) / ARCSEC_PER_ARCMIN))
    return out


def _thin(t: np.ndarray, a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    step = max(1, len(t) // MAX_POINTS_PER_CURVE)
    return t[::step], a[::step]


def _single_lines(ax: Any, results: Mapping[str, Any], label: Label, fmt: Callable[[float], str]) -> None:
    """The evaluation's lines of one test: secants, lost-motion points, backlash."""
    sides = (results.get("per_direction") or {})
    secant_drawn = False
    for name, sign in (("positive", 1.0), ("negative", -1.0)):
        side = sides.get(name)
        if not isinstance(side, Mapping):
            continue
        interval = side.get("interval_nm")
        rigidity, torsion = side.get("rigidity_nm_per_arcmin"), side.get("torsion_angle_arcsec")
        if isinstance(interval, list | tuple) and len(interval) == 2 and isinstance(rigidity, int | float) \
                and rigidity > 0 and isinstance(torsion, int | float):
            lo, hi = float(interval[0]), float(interval[1])
            top = float(torsion) / ARCSEC_PER_ARCMIN
            ax.plot([sign * lo, sign * hi], [sign * (top - (hi - lo) / rigidity), sign * top], color=LINE, lw=2.0,
                    label=None if secant_drawn else label("legend_secant", lo=fmt(lo), hi=fmt(hi)), zorder=4)
            ax.plot([0.0, sign * hi], [sign * (top - hi / rigidity), sign * top], color=LINE, lw=0.8, ls="--",
                    zorder=3)
            secant_drawn = True
    torque_lm = results.get("lost_motion_torque_nm")
    up, down = ((sides.get(n) or {}).get("half_lost_motion_arcsec") for n in ("positive", "negative"))
    if isinstance(torque_lm, int | float) and isinstance(up, int | float) and isinstance(down, int | float):
        xs = [float(torque_lm), -float(torque_lm)]
        ys = [float(up) / ARCSEC_PER_ARCMIN, -float(down) / ARCSEC_PER_ARCMIN]
        ax.plot(xs, ys, ls="none", marker="D", ms=5, color="#2e8b57", zorder=5,
                label=label("legend_lost_motion", torque=fmt(float(torque_lm))))
    backlash = results.get("backlash_arcsec")
    if isinstance(backlash, int | float) and backlash > 0:
        half = float(backlash) / 2.0 / ARCSEC_PER_ARCMIN
        ax.plot([0.0, 0.0], [-half, half], color="#8e44ad", lw=3.0, solid_capstyle="butt", zorder=5,
                label=label("legend_backlash"))


def _stage_lines(ax: Any, results: Mapping[str, Any], label: Label, fmt: Callable[[float], str]) -> None:
    """Where a test of several stages evaluated: the rigidity interval and the lost-motion torque."""
    side = (results.get("per_direction") or {}).get("positive")
    interval = side.get("interval_nm") if isinstance(side, Mapping) else None
    if isinstance(interval, list | tuple) and len(interval) == 2:
        lo, hi = float(interval[0]), float(interval[1])
        for sign in (1.0, -1.0):
            ax.axvspan(sign * lo, sign * hi, color="#f2d7c4", alpha=0.5, lw=0,
                       label=label("legend_interval") if sign > 0 else None, zorder=0)
    torque_lm = results.get("lost_motion_torque_nm")
    if isinstance(torque_lm, int | float) and torque_lm > 0:
        for sign in (1.0, -1.0):
            ax.axvline(sign * float(torque_lm), color="#2e8b57", lw=0.9, ls="--", zorder=1,
                       label=label("legend_lost_motion_torque", torque=fmt(float(torque_lm))) if sign > 0 else None)


def loop_figure_svg(columns: Mapping[str, np.ndarray], results: Mapping[str, Any] | None, label: Label,
                    fmt: Callable[[float], str] = lambda v: f"{v:g}") -> str | None:
    """The figure as SVG text (glyphs as paths), or None when the run recorded no samples. ``label(key, **fields)``
    gives each text (axis names, legend entries); ``fmt`` renders a torque for a label."""
    loops = relative_loops(columns, results)
    if not loops:
        return None
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6.6, 4.1))
    ax = fig.add_subplot()
    res = results or {}
    stages = res.get("positions") or res.get("rates") or []
    for i, (stage, t, a) in enumerate(loops):
        t, a = _thin(t, a)
        if stage is None:
            ax.plot(t, a, lw=0.9, color=COLOURS[0], label=label("legend_measured"), zorder=2)
            continue
        entry = stages[stage - 1] if 0 < stage <= len(stages) and isinstance(stages[stage - 1], Mapping) else {}
        where = entry.get("position_deg" if res.get("positions") else "rate_nm_per_s")
        shown = f"{float(where):g}" if isinstance(where, int | float) else "?"
        name = label("legend_position" if res.get("positions") else "legend_rate", value=shown)
        ax.plot(t, a, lw=0.8, color=COLOURS[i % len(COLOURS)], label=name, zorder=2)
    if loops[0][0] is None:
        _single_lines(ax, res, label, fmt)
    else:
        _stage_lines(ax, res, label, fmt)
    ax.axhline(0, color="#888", lw=0.5, zorder=1)
    ax.axvline(0, color="#888", lw=0.5, zorder=1)
    ax.set_xlabel(label("axis_torque"))
    ax.set_ylabel(label("axis_twist"))
    ax.grid(alpha=0.3)
    ax.legend(loc="upper left", fontsize=7.5, framealpha=0.9)
    fig.tight_layout()
    buf = io.StringIO()
    fig.savefig(buf, format="svg")
    svg = buf.getvalue()
    return svg[svg.find("<svg"):]

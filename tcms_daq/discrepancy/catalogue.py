"""The catalogue of named physical effects the discrepancy workflow can add to the simulated angle.

Each effect is a signature added to the simulated angle θ_sim (″), written with the names of the public
contract (JSON, reports and model files use them exactly):

==================== ============================================== =======================================
name                 signature added to θ_sim                       parameters
==================== ============================================== =======================================
time_skew            θ_sim(t + τ) − θ_sim(t) (exact re-evaluation)  skew_s (> 0: the torque channel lags)
thermal_drift        r·(t − t0)                                     rate_arcsec_per_s
bending_deformation  c·T²                                           coef_arcsec_per_nm2
torsion_offset       c·T                                            coef_arcsec_per_nm
scale_error          s·θ_sim                                        ratio
interpolation_error  A·sin(2π·θ_sim/P + ψ), P = signal period or ½  period_arcsec, amplitude_arcsec, phase_rad
periodic_error       the same at another period found by search     period_arcsec, amplitude_arcsec, phase_rad
backlash             −(b/2)·d, d = +1 loading / −1 unloading        backlash_arcsec (> 0: a wider loop)
torque_zero_offset   −T0·dθ_sim/dT (slope along the simulated trace)  offset_nm
nonlinear_stiffness  c·T³ (odd in torque)                           coef_arcsec_per_nm3
==================== ============================================== =======================================

A constant offset is always fitted and is not an effect. Linear effects give columns whose coefficients are
the parameters; nonlinear ones (period, skew) also have a bounded grid that the workflow searches inside each
training fold and refines by parabolic interpolation. ``signature`` evaluates an effect from its parameters
(used to apply a model file to a simulation and by ``sim.effects``).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from tcms_daq.discrepancy.design import DesignData

BUILT_IN: tuple[str, ...] = (
    "time_skew", "thermal_drift", "bending_deformation", "torsion_offset", "scale_error",
    "interpolation_error", "periodic_error", "backlash", "torque_zero_offset", "nonlinear_stiffness",
)
EFFECT_NAMES: list[str] = list(BUILT_IN)  # built-in, then declared ones (register_effect, entry points)

MAX_SKEW_S = 0.25
PERIOD_EXCLUSION = 0.04  # periodic_error keeps 4 % away from the signal period and its half
MAX_PERIOD_GRID = 240
# A periodic term with fewer cycles than this inside the angle span is fitted, but cannot be told from a smooth
# shape the catalogue does not have (c·|T| was fitted within the noise by bending + 1.8 cycles of a sine).
MIN_IDENTIFIED_CYCLES = 2.5


@dataclass(frozen=True)
class Effect:
    """Static description of a catalogue effect (what the report and the aliasing screen need)."""

    name: str
    parameters: tuple[str, ...]
    units: tuple[str, ...]
    description: str
    parity: str  # "even" (same sign loading/unloading), "odd" (flips with the load direction), "time"
    rate_dependent: bool
    needs_time: bool
    nonlinear: str | None  # name of the grid-searched parameter, if any
    fixed_gain: bool  # enters with gain 1 (a re-evaluated simulation), not through a linear coefficient
    plausible: str  # the plausibility rule in words


CATALOGUE: dict[str, Effect] = {e.name: e for e in (
    Effect("time_skew", ("skew_s",), ("s",), "torque channel lags the angle: simulation taken at t + τ",
           "odd", True, True, "skew_s", True, f"|τ| ≤ {MAX_SKEW_S} s"),
    Effect("thermal_drift", ("rate_arcsec_per_s",), ("″/s",), "linear drift of the angle with time",
           "time", False, True, None, False, "|r| ≤ 0.1 ″/s"),
    Effect("bending_deformation", ("coef_arcsec_per_nm2",), ("″/(N·m)²",),
           "bending of the measuring point, even in torque (c·T²)", "even", False, False, None, False,
           "|c·T_max²| ≤ 20 % of the simulated angle span"),
    Effect("torsion_offset", ("coef_arcsec_per_nm",), ("″/N·m",),
           "shaft torsion between the measuring planes (c·T)", "even", False, False, None, False,
           "|c·T_max| ≤ 20 % of the simulated angle span"),
    Effect("scale_error", ("ratio",), ("1",), "encoder/measuring-chain scale error (s·θ_sim)", "even", False,
           False, None, False, "|s| ≤ 0.1"),
    Effect("interpolation_error", ("period_arcsec", "amplitude_arcsec", "phase_rad"), ("″", "″", "rad"),
           "encoder interpolation error at the signal period or its half", "even", False, False,
           "period_arcsec", False, "amplitude ≤ 5 % of the period"),
    Effect("periodic_error", ("period_arcsec", "amplitude_arcsec", "phase_rad"), ("″", "″", "rad"),
           "periodic error in the angle at a period found by search", "even", False, False, "period_arcsec",
           False, "amplitude ≤ 10 ″ and ≤ 10 % of the period; ≥ 1.5 periods inside the angle span"),
    Effect("backlash", ("backlash_arcsec",), ("″",), "extra loop width ±b/2 by load direction", "odd", False,
           False, None, False, "|b| ≤ 120 ″"),
    Effect("torque_zero_offset", ("offset_nm",), ("N·m",),
           "torque sensor zero offset: the angle shifted along the simulated curve by T0 (−T0·dθ/dT)", "even",
           False, False, None, False, "|T0| ≤ 5 % of the torque span"),
    Effect("nonlinear_stiffness", ("coef_arcsec_per_nm3",), ("″/(N·m)³",),
           "stiffness that changes with torque, odd in torque (c·T³)", "even", False, False, None, False,
           "|c·T_max³| ≤ 20 % of the simulated angle span"),
)}


# ----------------------------------------------------------------------------------------------------------
# Effects a user declares (without editing this module)

ENTRY_POINT_GROUP = "tcms_daq.effects"


@dataclass(frozen=True)
class DeclaredEffect:
    """An effect in declared form: one parameter times a column computed from the aligned design data
    (``DesignData``: time, torque, simulated angle, load direction, slope …), in arcsec per unit of the
    parameter. It is a candidate like the built-in ones (selection, aliases, verdict, model file, apply).

    Register it with :func:`register_effect`, or from an installed package through an entry point of the group
    ``tcms_daq.effects`` whose object is a ``DeclaredEffect`` (loaded by :func:`load_entry_point_effects`).
    """

    name: str
    parameter: str
    unit: str
    description: str
    column: Callable[[DesignData], np.ndarray]
    max_abs: float  # plausible |parameter|
    needs_time: bool = False
    parity: str = "even"


DECLARED: dict[str, DeclaredEffect] = {}


def register_effect(effect: DeclaredEffect) -> None:
    """Add a declared effect to the catalogue (ValueError for a name the built-in catalogue has)."""
    if not effect.name.isidentifier() or not effect.parameter.isidentifier():
        raise ValueError(f"effect and parameter names must be identifiers: {effect.name!r}, {effect.parameter!r}")
    if effect.name in BUILT_IN:
        raise ValueError(f"{effect.name!r} is a built-in effect")
    if not effect.max_abs > 0:
        raise ValueError(f"{effect.name}: max_abs must be > 0")
    DECLARED[effect.name] = effect
    CATALOGUE[effect.name] = Effect(effect.name, (effect.parameter,), (effect.unit,), effect.description,
                                    effect.parity, False, effect.needs_time, None, False,
                                    f"|{effect.parameter}| ≤ {effect.max_abs:g}")
    if effect.name not in EFFECT_NAMES:
        EFFECT_NAMES.append(effect.name)


def unregister_effect(name: str) -> None:
    if DECLARED.pop(name, None) is not None:
        CATALOGUE.pop(name, None)
        EFFECT_NAMES.remove(name)


_ENTRY_POINTS_LOADED = False


def load_entry_point_effects() -> list[str]:
    """Register the declared effects of installed packages (group ``tcms_daq.effects``), once; their names."""
    global _ENTRY_POINTS_LOADED
    if _ENTRY_POINTS_LOADED:
        return []
    _ENTRY_POINTS_LOADED = True
    from importlib.metadata import entry_points

    added = []
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        effect = ep.load()
        if not isinstance(effect, DeclaredEffect):
            raise TypeError(f"entry point {ep.name!r} of {ENTRY_POINT_GROUP} is not a DeclaredEffect")
        register_effect(effect)
        added.append(effect.name)
    return added


# ----------------------------------------------------------------------------------------------------------
# Signals and columns


def skew_shift(data: DesignData, skew_s: float, rows: np.ndarray | None = None) -> np.ndarray:
    """θ_sim(t + τ) − θ_sim(t), interpolating the simulated angle in time within each continuous segment
    (at ``rows`` only, if given)."""
    if rows is None:
        out = np.zeros(len(data))
        for idx in data.segment_rows:
            if len(idx) < 2:
                continue
            t = data.time_s[idx]
            th = data.sim_angle_arcsec[idx]
            out[idx] = np.interp(t + skew_s, t, th) - th
        return out
    out = np.zeros(len(rows))
    seg = data.segments[rows]
    for idx in data.segment_rows:
        if len(idx) < 2:
            continue
        mine = np.flatnonzero(seg == data.segments[idx[0]])
        if len(mine) == 0:
            continue
        t = data.time_s[idx]
        th = data.sim_angle_arcsec[idx]
        r = rows[mine]
        out[mine] = np.interp(data.time_s[r] + skew_s, t, th) - data.sim_angle_arcsec[r]
    return out


def sincos(theta_arcsec: np.ndarray, period_arcsec: float) -> np.ndarray:
    x = (2.0 * math.pi / period_arcsec) * theta_arcsec
    return np.column_stack((np.sin(x), np.cos(x)))


def skew_grid(data: DesignData) -> np.ndarray:
    dt = np.diff(data.time_s)
    pos = dt[dt > 0]
    step = float(np.median(pos)) if len(pos) else 0.01
    seg_len = min(float(np.ptp(data.time_s[data.segments == s])) for s in np.unique(data.segments))
    tmax = min(MAX_SKEW_S, max(0.05 * seg_len, 3 * step))
    n = int(min(161, max(21, 2 * tmax / (0.5 * step) + 1)))
    return np.linspace(-tmax, tmax, n)


def periodic_grid(data: DesignData) -> np.ndarray:
    """Periods for the periodic_error search: uniform in frequency, ≥ 1.5 cycles inside the angle span."""
    theta = data.sim_angle_arcsec
    span = float(np.ptp(theta))
    if span <= 0:
        return np.zeros(0)
    steps = np.abs(np.diff(theta))
    steps = steps[steps > 0]
    typical = float(np.percentile(steps, 75)) if len(steps) else span / 10
    p_min = max(4.0 * typical, data.signal_period_arcsec / 8.0)
    p_max = span / 1.5
    if p_max <= p_min:
        return np.zeros(0)
    df = 1.0 / (3.0 * span)
    f = np.arange(1.0 / p_max, 1.0 / p_min + df / 2, df)
    if len(f) > MAX_PERIOD_GRID:
        f = np.linspace(1.0 / p_max, 1.0 / p_min, MAX_PERIOD_GRID)
    periods = 1.0 / f
    keep = np.ones(len(periods), dtype=bool)
    for p in interpolation_periods(data):
        # not resolvable from the signal period within the span (< 1 cycle apart): that is interpolation_error
        keep &= (np.abs(periods / p - 1.0) > PERIOD_EXCLUSION) & (np.abs(f - 1.0 / p) >= 1.0 / span)
    return periods[keep]


def interpolation_periods(data: DesignData) -> np.ndarray:
    return np.array([data.signal_period_arcsec, data.signal_period_arcsec / 2.0])


def grid(name: str, data: DesignData) -> np.ndarray | None:
    if name == "time_skew":
        return skew_grid(data)
    if name == "periodic_error":
        return periodic_grid(data)
    if name == "interpolation_error":
        return interpolation_periods(data)
    return None


def _value(nl: float | None, name: str) -> float:
    """The nonlinear value an effect needs (its period, its time skew)."""
    if nl is None:
        raise ValueError(f"effect {name!r} needs its nonlinear value (period or skew)")
    return float(nl)


def columns(name: str, data: DesignData, nl: float | None = None) -> np.ndarray:
    """Design columns (n × m) of a linear effect, or the fixed-gain signature (n × 1) of ``time_skew``."""
    if name == "time_skew":
        return skew_shift(data, _value(nl, name))[:, None]
    if name == "thermal_drift":
        return (data.time_s - data.time_s[0])[:, None]
    if name == "bending_deformation":
        return (data.torque_nm ** 2)[:, None]
    if name == "torsion_offset":
        return data.torque_nm[:, None]
    if name == "scale_error":
        return data.sim_angle_arcsec[:, None]
    if name in ("interpolation_error", "periodic_error"):
        return sincos(data.sim_angle_arcsec, _value(nl, name))
    if name == "backlash":
        return (-0.5 * data.direction)[:, None]
    if name == "torque_zero_offset":
        return (-data.slope_arcsec_per_nm)[:, None]
    if name == "nonlinear_stiffness":
        return (data.torque_nm ** 3)[:, None]
    if name in DECLARED:
        column = np.asarray(DECLARED[name].column(data), dtype=float)
        if column.shape != (len(data),) or not np.all(np.isfinite(column)):
            raise ValueError(f"declared effect {name!r}: its column must be {len(data)} finite values")
        return column[:, None]
    raise KeyError(name)


def columns_at(name: str, data: DesignData, nl: float | None, rows: np.ndarray) -> np.ndarray:
    """``columns(name, data, nl)[rows]`` without evaluating the other rows (for nonlinear values)."""
    if name == "time_skew":
        return skew_shift(data, _value(nl, name), rows)[:, None]
    if name in ("interpolation_error", "periodic_error"):
        return sincos(data.sim_angle_arcsec[rows], _value(nl, name))
    return columns(name, data, nl)[rows]


def parameters(name: str, coef: np.ndarray, nl: float | None) -> dict[str, float]:
    """Contract parameters from fitted coefficients (and the nonlinear value)."""
    if name == "time_skew":
        return {"skew_s": _value(nl, name)}
    if name in ("interpolation_error", "periodic_error"):
        a, b = float(coef[0]), float(coef[1])  # a·sin x + b·cos x = A·sin(x + ψ)
        return {"period_arcsec": _value(nl, name), "amplitude_arcsec": math.hypot(a, b), "phase_rad": math.atan2(b, a)}
    key = CATALOGUE[name].parameters[0]
    return {key: float(coef[0])}


def signature(name: str, data: DesignData, params: dict[str, float]) -> np.ndarray:
    """The effect's contribution (″) to the simulated angle, from its contract parameters."""
    if name == "time_skew":
        return skew_shift(data, params["skew_s"])
    if name in ("interpolation_error", "periodic_error"):
        x = 2.0 * math.pi * data.sim_angle_arcsec / params["period_arcsec"] + params["phase_rad"]
        return params["amplitude_arcsec"] * np.sin(x)
    key = CATALOGUE[name].parameters[0]
    return columns(name, data)[:, 0] * params[key]


def identification_limit(name: str, params: dict[str, float], data: DesignData) -> str | None:
    """None if a fitted term is identified by its form, else why it may stand in for another shape.

    A plausible term can still be a look-alike of something outside the catalogue: a free-period sine over
    fewer than ``MIN_IDENTIFIED_CYCLES`` cycles bends like any smooth curve. Such a name is provisional."""
    if name == "periodic_error":
        cycles = float(np.ptp(data.sim_angle_arcsec)) / params["period_arcsec"]
        if cycles < MIN_IDENTIFIED_CYCLES:
            return (f"{cycles:.1f} cycles of its {params['period_arcsec']:.4g}″ period inside the angle span "
                    f"(< {MIN_IDENTIFIED_CYCLES}): it cannot be told from a smooth shape outside the catalogue")
    return None


def plausibility(name: str, params: dict[str, float], data: DesignData) -> str | None:
    """None if the fitted value is physically plausible, else the reason in one line."""
    if name in DECLARED:
        d = DECLARED[name]
        return f"|{d.parameter}| above {d.max_abs:g}" if abs(params[d.parameter]) > d.max_abs else None
    span = float(np.ptp(data.sim_angle_arcsec)) or 1.0
    tmax = float(np.max(np.abs(data.torque_nm))) or 1.0
    tspan = float(np.ptp(data.torque_nm)) or 1.0
    if name == "time_skew" and abs(params["skew_s"]) > MAX_SKEW_S:
        return f"skew {params['skew_s']:.3g} s exceeds {MAX_SKEW_S} s"
    if name == "thermal_drift" and abs(params["rate_arcsec_per_s"]) > 0.1:
        return f"drift {params['rate_arcsec_per_s']:.3g} ″/s exceeds 0.1 ″/s"
    if name == "bending_deformation" and abs(params["coef_arcsec_per_nm2"]) * tmax ** 2 > 0.2 * span:
        return "bending term larger than 20 % of the angle span"
    if name == "torsion_offset" and abs(params["coef_arcsec_per_nm"]) * tmax > 0.2 * span:
        return "torsion term larger than 20 % of the angle span"
    if name == "scale_error" and abs(params["ratio"]) > 0.1:
        return f"scale ratio {params['ratio']:.3g} exceeds 0.1"
    if name == "interpolation_error" and params["amplitude_arcsec"] > 0.05 * params["period_arcsec"]:
        return "interpolation amplitude above 5 % of the signal period"
    if name == "periodic_error":
        if params["amplitude_arcsec"] > min(10.0, 0.1 * params["period_arcsec"]):
            return "periodic amplitude above 10 ″ or 10 % of its period"
        if params["period_arcsec"] > span / 1.5:
            return "fewer than 1.5 periods inside the angle span"
    if name == "nonlinear_stiffness" and abs(params["coef_arcsec_per_nm3"]) * tmax ** 3 > 0.2 * span:
        return "cubic stiffness term larger than 20 % of the angle span"
    if name == "backlash" and abs(params["backlash_arcsec"]) > 120.0:
        return "backlash above 120 ″"
    if name == "torque_zero_offset" and abs(params["offset_nm"]) > 0.05 * tspan:
        return "torque offset above 5 % of the torque span"
    return None


def angle_follows_torque(data: DesignData) -> bool:
    """True when the design loads in one direction only: the angle is then a one-to-one function of the
    torque, and any error periodic in the angle is also some smooth function of the torque."""
    return bool(np.all(data.direction == data.direction[0]))


# A free-period periodic error in a one-directional design: which catalogue effect stands for "some other
# function of the torque" in the alias report.
ONE_TO_ONE_ALIAS = "nonlinear_stiffness"


def cat_fixed_gain(name: str) -> bool:
    return CATALOGUE[name].fixed_gain


def available(name: str, data: DesignData) -> str | None:
    """None if the effect can be identified in this design at all, else why not (one line)."""
    eff = CATALOGUE[name]
    if eff.needs_time and not data.has_time:
        return "needs time_s"
    if name == "backlash" and np.all(data.direction == data.direction[0]):
        return "no load reversal in the data: a direction-odd term equals the constant offset"
    if name == "time_skew":
        dt = np.diff(data.time_s)
        if not np.any(dt > 0):
            return "time_s does not increase"
    if name == "periodic_error" and len(periodic_grid(data)) == 0:
        return "angle span too small for a period search"
    if eff.nonlinear:
        g = grid(name, data)
        if g is None or len(g) == 0:
            return "no admissible values for its nonlinear parameter in this design"
        if cat_fixed_gain(name):
            return None
        cols = columns(name, data, float(g[0]))
    else:
        cols = columns(name, data)
    centred = cols - cols.mean(axis=0)
    if not np.any(np.abs(centred) > 1e-9 * (1.0 + np.abs(cols).max())):
        return "constant in this design (indistinguishable from the offset)"
    return None


# ----------------------------------------------------------------------------------------------------------
# Aliasing: what separates two look-alike effects

_SEPARATING: dict[frozenset[str], str] = {
    frozenset({"torsion_offset", "scale_error"}):
        "vary the lever arm or radial load independently of the torque, or move the measuring plane axially "
        "(or test a reducer of another stiffness): a scale error follows the angle, shaft torsion the torque",
    frozenset({"bending_deformation", "scale_error"}):
        "load in both directions through zero (±T): bending c·T² is even in torque, a scale error is odd",
    frozenset({"bending_deformation", "torsion_offset"}):
        "load in both directions through zero (±T): c·T² is even in torque, c·T is odd",
    frozenset({"time_skew", "backlash"}):
        "repeat at a second loading rate (a skew grows with the rate, backlash does not) or check the channel "
        "timing with a hardware loopback",
    frozenset({"periodic_error", "nonlinear_stiffness"}):
        "load and unload (±T) and repeat with the encoder mounted at another angle (a coarse angle and half a "
        "signal period) with the reference recorded simultaneously: an error periodic in the encoder angle "
        "moves with the mounting angle, a torque-dependent difference (stiffness, seating, a separate "
        "reference run) does not",
    frozenset({"torque_zero_offset", "backlash"}):
        "tare at zero torque before and after and load symmetrically through zero",
}


def separating_experiment(names: list[str]) -> str:
    """The experiment that would tell the effects in ``names`` apart (one sentence)."""
    names = list(dict.fromkeys(names))
    found: list[str] = []
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            text = _SEPARATING.get(frozenset({a, b}))
            if text is None:
                pair = {a, b}
                if "thermal_drift" in pair:
                    text = ("record loading and unloading with zero-torque dwells at start and end and log "
                            "the temperature: drift keeps growing with time while the torque goes back down")
                elif pair & {"interpolation_error", "periodic_error"}:
                    text = ("repeat with the encoder mounting angle shifted by half a signal period and by a "
                            "coarse angle: an encoder-periodic term moves with the mounting angle, a torque "
                            "term does not")
                elif "time_skew" in pair:
                    text = ("repeat at a second loading rate and with dwells: a skew vanishes in a dwell and "
                            "grows with the rate")
                elif "torque_zero_offset" in pair:
                    text = ("tare at zero torque before and after and load symmetrically through zero: a "
                            "torque offset moves the curve along the torque axis, most in the lost-motion zone")
                else:
                    text = "load in both directions at two rates and two encoder mounting angles"
            if text not in found:
                found.append(text)
    return "; ".join(found)

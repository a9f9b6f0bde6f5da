"""Each named physical effect defined once (pure numpy): its formula, its design columns for identification, its
streaming form for the simulated bench, its plausibility rule and its optional compensator term.

An effect is a term added to the simulated angle θ_sim (″), read from one vocabulary of signals (:class:`Signals`):
elapsed time t (s), torque T (N·m), the angle θ (″), the load direction d (+1 loading, −1 unloading) and the slope
dθ/dT along the trace (″/N·m). The discrepancy workflow reads them from the aligned measured/simulated pair
(``DesignData``); the simulated bench (``tcms_daq.sim.effects``) reads them from each batch, with the direction and
slope carried across batches, so the same formula hides the effect and identifies it.

==================== ============================================== =======================================
name                 term added to θ_sim                            parameters
==================== ============================================== =======================================
time_skew            θ_sim(t + τ) − θ_sim(t) (exact re-evaluation)  skew_s (> 0: the torque channel lags)
thermal_drift        r·(t − t0)                                     rate_arcsec_per_s
bending_deformation  c·T²                                           coef_arcsec_per_nm2
torsion_offset       c·T                                            coef_arcsec_per_nm
scale_error          s·θ_sim                                        ratio
interpolation_error  A·sin(2π·θ_sim/P + ψ), P = signal period or ½  period_arcsec, amplitude_arcsec, phase_rad
periodic_error       the same at another period found by search     period_arcsec, amplitude_arcsec, phase_rad
backlash             −(b/2)·d, d = +1 loading / −1 unloading        backlash_arcsec (> 0: a wider loop)
torque_zero_offset   θ_hf(T − T0) − θ_hf(T): the simulated curve's     offset_nm (> 0: the reading is high)
                     history-free part read T0 along the torque axis
nonlinear_stiffness  c·T³ (odd in torque)                           coef_arcsec_per_nm3
==================== ============================================== =======================================

The built-in effects are registered with :func:`register_effect`, the call a user's effect goes through (directly or
from an installed package's entry point of the group ``tcms_daq.effects``). This module is the only place an
effect's name is written: other modules look effects up in :data:`REGISTRY` or use the name constants below.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol, cast

import numpy as np

if TYPE_CHECKING:
    from tcms_daq.compensation.terms import Term
    from tcms_daq.discrepancy.design import DesignData

ENTRY_POINT_GROUP = "tcms_daq.effects"

MAX_SKEW_S = 0.25
TORQUE_OFFSET_SHARE = 0.05  # a plausible torque zero offset is at most this share of the torque span
TORQUE_OFFSET_GRID = 161  # grid values over ±1.2 × the plausible range
PERIOD_EXCLUSION = 0.04  # periodic_error keeps 4 % away from the signal period and its half
MAX_PERIOD_GRID = 240
# A periodic term with fewer cycles than this inside the angle span is fitted, but cannot be told from a smooth
# shape the catalogue does not have (c·|T| was fitted within the noise by bending + 1.8 cycles of a sine).
MIN_IDENTIFIED_CYCLES = 2.5

Params = Mapping[str, float]


class Signals(Protocol):
    """What an effect's formula reads; ``DesignData`` and the simulator's :class:`BatchSignals` provide it."""

    @property
    def elapsed_s(self) -> np.ndarray: ...  # s since the start of the trace
    @property
    def torque_nm(self) -> np.ndarray: ...
    @property
    def sim_angle_arcsec(self) -> np.ndarray: ...  # the angle the effect acts on (″)
    @property
    def direction(self) -> np.ndarray: ...  # +1 loading, −1 unloading
    @property
    def slope_arcsec_per_nm(self) -> np.ndarray: ...  # dθ/dT along the trace


@dataclass(frozen=True)
class BatchSignals:
    """One batch of the simulated bench in the effects' vocabulary (see :class:`Signals`)."""

    elapsed_s: np.ndarray
    torque_nm: np.ndarray
    sim_angle_arcsec: np.ndarray
    direction: np.ndarray
    slope_arcsec_per_nm: np.ndarray


class Streaming(Protocol):
    """An effect in the simulated bench: a stateful transform of each batch (a run cut into batches gives the same
    result as in one piece)."""

    def torque_signal_nm(self, time_s: np.ndarray, torque_signal_nm: np.ndarray) -> np.ndarray: ...
    def angle_arcsec(self, signals: Signals) -> np.ndarray: ...


@dataclass
class EffectDefinition:
    """One effect: description, parameters with units, design columns, formula, plausibility, streaming form."""

    name: str
    parameters: tuple[str, ...]
    units: tuple[str, ...]
    description: str
    parity: str  # "even" (same sign loading/unloading), "odd" (flips with the load direction), "time"
    plausible: str  # the plausibility rule in words
    rate_dependent: bool = False
    needs_time: bool = False
    nonlinear: str | None = None  # name of the grid-searched parameter, if any
    fixed_gain: bool = False  # enters with gain 1 (a re-evaluated simulation), not through a linear coefficient
    # how the grid's best value is refined: "parabolic" in the value, "frequency" (parabolic in 1/value: a free
    # period, whose shape is no evidence where the angle is a function of the torque), "discrete" (grid values only)
    grid_refine: str = "parabolic"
    # the simulator's defaults for parameters a [sim.effects] table may leave out; a size a user would meet
    sim_defaults: dict[str, float] = field(default_factory=dict)
    typical: dict[str, float] = field(default_factory=dict)
    # the compensator term, or why the effect stays in the bench model
    compensator: Callable[[Params], Term] | None = None
    kept_in_model: str = "a declared effect: kept in the bench model"
    simulated: bool = True  # the simulated bench can hide it ([sim.effects])

    @property
    def primary(self) -> str:
        """The parameter that switches the effect off at 0 (the amplitude of a periodic one)."""
        return "amplitude_arcsec" if "amplitude_arcsec" in self.parameters else self.parameters[0]

    # -- identification --------------------------------------------------------------------------------------
    def columns(self, data: DesignData, nl: float | None = None, rows: np.ndarray | None = None) -> np.ndarray:
        """Design columns (n × m) whose coefficients are the linear parameters (at ``rows`` if given)."""
        raise NotImplementedError

    def parameters_from(self, coef: np.ndarray, nl: float | None) -> dict[str, float]:
        """Contract parameters from fitted coefficients (and the nonlinear value)."""
        return {self.parameters[0]: float(coef[0])}

    def grid(self, data: DesignData) -> np.ndarray | None:
        """Admissible values of the nonlinear parameter in this design (None: a linear effect)."""
        return None

    def unavailable(self, data: DesignData) -> str | None:
        """Why the effect cannot be identified in this design at all (beyond being constant), or None."""
        if self.needs_time and not data.has_time:
            return "needs time_s"
        return None

    def implausible(self, params: Params, data: DesignData) -> str | None:
        """None if the fitted value is physically plausible, else the reason in one line."""
        return None

    def identification_limit(self, params: Params, data: DesignData) -> str | None:
        """None if a fitted term is identified by its form, else why it may stand in for another shape."""
        return None

    # -- the formula -------------------------------------------------------------------------------------------
    def formula(self, signals: Signals, params: Params) -> np.ndarray:
        """The effect's contribution (″) to the angle, from its contract parameters."""
        raise NotImplementedError

    def signature(self, data: DesignData, params: Params) -> np.ndarray:
        """The contribution on a design (the re-simulation when a model is applied)."""
        return self.formula(data, params)

    # -- simulation --------------------------------------------------------------------------------------------
    def streaming(self, params: Params) -> Streaming:
        return _AngleTerm(self, dict(params))


@dataclass
class _AngleTerm:
    effect: EffectDefinition
    params: dict[str, float]

    def torque_signal_nm(self, time_s: np.ndarray, torque_signal_nm: np.ndarray) -> np.ndarray:
        return torque_signal_nm

    def angle_arcsec(self, signals: Signals) -> np.ndarray:
        return self.effect.formula(signals, self.params)


@dataclass
class LinearEffect(EffectDefinition):
    """One parameter times one column of the signals (″ per unit of the parameter)."""

    column: Callable[[Signals], np.ndarray] = field(default=lambda s: np.zeros(len(s.torque_nm)))
    bound: Callable[[float, DesignData], str | None] = field(default=lambda v, d: None)

    def columns(self, data: DesignData, nl: float | None = None, rows: np.ndarray | None = None) -> np.ndarray:
        col = self.column(data)[:, None]
        return col if rows is None else col[rows]

    def implausible(self, params: Params, data: DesignData) -> str | None:
        return self.bound(float(params[self.parameters[0]]), data)

    def formula(self, signals: Signals, params: Params) -> np.ndarray:
        return float(params[self.parameters[0]]) * self.column(signals)


@dataclass
class DeclaredEffect:
    """A user's effect in declared form: one parameter times a column computed from the aligned design data
    (``DesignData``: time, torque, simulated angle, load direction, slope …), in arcsec per unit of the
    parameter. It is a candidate like the built-in ones (selection, aliases, verdict, model file, apply).

    Register it with :func:`register_effect`, or from an installed package through an entry point of the group
    ``tcms_daq.effects`` whose object is a ``DeclaredEffect`` or an :class:`EffectDefinition`.
    """

    name: str
    parameter: str
    unit: str
    description: str
    column: Callable[[DesignData], np.ndarray]
    max_abs: float  # plausible |parameter|
    needs_time: bool = False
    parity: str = "even"

    def definition(self) -> EffectDefinition:
        column = self.column
        name, parameter, max_abs = self.name, self.parameter, self.max_abs

        def checked(data: Signals) -> np.ndarray:
            values = np.asarray(column(cast("DesignData", data)), dtype=float)  # a design in identification
            n = len(data.torque_nm)
            if values.shape != (n,) or not np.all(np.isfinite(values)):
                raise ValueError(f"declared effect {name!r}: its column must be {n} finite values")
            return values

        return LinearEffect(
            self.name, (self.parameter,), (self.unit,), self.description, self.parity,
            f"|{self.parameter}| ≤ {self.max_abs:g}", needs_time=self.needs_time, simulated=False,
            column=checked, bound=lambda v, d: f"|{parameter}| above {max_abs:g}" if abs(v) > max_abs else None)


# ----------------------------------------------------------------------------------------------------------
# The registry

REGISTRY: dict[str, EffectDefinition] = {}
EFFECT_NAMES: list[str] = []  # the registry's names in registration order: built-in, then declared ones
BUILT_IN: tuple[str, ...] = ()
DECLARED: dict[str, EffectDefinition] = {}


def register_effect(effect: EffectDefinition | DeclaredEffect, *, built_in: bool = False) -> EffectDefinition:
    """Add an effect to the registry (ValueError for a name or parameter that is not an identifier, a name
    already registered, or an invalid bound). Built-in and user effects go through this one call."""
    definition = effect.definition() if isinstance(effect, DeclaredEffect) else effect
    if isinstance(effect, DeclaredEffect) and not effect.max_abs > 0:
        raise ValueError(f"{effect.name}: max_abs must be > 0")
    if not definition.name.isidentifier() or not all(p.isidentifier() for p in definition.parameters):
        raise ValueError(f"effect and parameter names must be identifiers: {definition.name!r}, "
                         f"{definition.parameters!r}")
    if definition.name in BUILT_IN:
        raise ValueError(f"{definition.name!r} is a built-in effect")
    if definition.name in REGISTRY and not (definition.name in DECLARED and not built_in):
        raise ValueError(f"{definition.name!r} is already registered")
    if len(definition.units) != len(definition.parameters):
        raise ValueError(f"{definition.name}: one unit per parameter")
    REGISTRY[definition.name] = definition
    if definition.name not in EFFECT_NAMES:
        EFFECT_NAMES.append(definition.name)
    if not built_in:
        DECLARED[definition.name] = definition
    return definition


def unregister_effect(name: str) -> None:
    """Remove a user's effect (built-in ones stay)."""
    if DECLARED.pop(name, None) is not None:
        REGISTRY.pop(name, None)
        EFFECT_NAMES.remove(name)


_ENTRY_POINTS_LOADED = False


def load_entry_point_effects() -> list[str]:
    """Register the effects of installed packages (group ``tcms_daq.effects``), once; their names."""
    global _ENTRY_POINTS_LOADED
    if _ENTRY_POINTS_LOADED:
        return []
    _ENTRY_POINTS_LOADED = True
    from importlib.metadata import entry_points

    added = []
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        effect = ep.load()
        if not isinstance(effect, DeclaredEffect | EffectDefinition):
            raise TypeError(f"entry point {ep.name!r} of {ENTRY_POINT_GROUP} is not a DeclaredEffect or an "
                            f"EffectDefinition")
        added.append(register_effect(effect).name)
    return added


# ----------------------------------------------------------------------------------------------------------
# Shared pieces


def _spans(data: DesignData) -> tuple[float, float, float]:
    """(angle span ″, max |T| N·m, torque span N·m), each at least 1 so a bound is never a division by 0."""
    return (float(np.ptp(data.sim_angle_arcsec)) or 1.0, float(np.max(np.abs(data.torque_nm))) or 1.0,
            float(np.ptp(data.torque_nm)) or 1.0)


def sincos(theta_arcsec: np.ndarray, period_arcsec: float) -> np.ndarray:
    x = (2.0 * math.pi / period_arcsec) * theta_arcsec
    return np.column_stack((np.sin(x), np.cos(x)))


def _value(nl: float | None, name: str) -> float:
    if nl is None:
        raise ValueError(f"effect {name!r} needs its nonlinear value (period or skew)")
    return float(nl)


def skew_shift(data: DesignData, skew_s: float, rows: np.ndarray | None = None) -> np.ndarray:
    """θ_sim(t + τ) − θ_sim(t), interpolating the simulated angle in time within each continuous segment
    (at ``rows`` only, if given) by monotone cubic pieces (PCHIP: no overshoot at a reversal). Linear pieces cut
    the corner of the lost-motion zone where it is crossed in one or two samples (600 N·m/s at 50 Hz: 12 N·m a
    sample against a 10.8 N·m zone): up to 0.6″ off at each zero crossing, spikes that kept run 2 of a hidden
    10 ms skew ``unexplained`` in the service's closed loop; 0.26″ with PCHIP."""
    out = np.zeros(len(data) if rows is None else len(rows))
    seg = None if rows is None else data.segments[rows]
    for idx in data.segment_rows:
        if len(idx) < 2:
            continue
        if rows is None:
            mine, at = idx, idx
        else:
            mine = np.flatnonzero(seg == data.segments[idx[0]])
            if len(mine) == 0:
                continue
            at = rows[mine]
        t = data.time_s[idx]
        shifted = data.angle_interpolant(int(data.segments[idx[0]]))(np.clip(data.time_s[at] + skew_s, t[0], t[-1]))
        out[mine] = shifted - data.sim_angle_arcsec[at]
    return out


def skew_grid(data: DesignData) -> np.ndarray:
    dt = np.diff(data.time_s)
    pos = dt[dt > 0]
    step = float(np.median(pos)) if len(pos) else 0.01
    seg_len = min(float(np.ptp(data.time_s[data.segments == s])) for s in np.unique(data.segments))
    tmax = min(MAX_SKEW_S, max(0.05 * seg_len, 3 * step))
    n = int(min(161, max(21, 2 * tmax / (0.5 * step) + 1)))
    return np.linspace(-tmax, tmax, n)


def torque_shift(data: DesignData, offset_nm: float, rows: np.ndarray | None = None) -> np.ndarray:
    """θ_hf(T − T0) − θ_hf(T) (″): the history-free part of the simulated curve (``DesignData.history_free``: the
    mean of its loading and unloading curves, continued straight beyond its ends) read ``offset_nm`` lower along
    the torque axis, at ``rows`` if given. A simulation driven by a reading T0 high is this much off; the friction
    loop, which follows the torque's increments, is not shifted."""
    grid, curve = data.history_free
    torque = data.torque_nm if rows is None else data.torque_nm[rows]
    here = data.history_free_on_rows if rows is None else data.history_free_on_rows[rows]
    return np.interp(torque - offset_nm, grid, curve) - here


def torque_offset_grid(data: DesignData) -> np.ndarray:
    """Torque offsets (N·m) searched: ±1.2 × the plausible range, so a best value beyond it shows as implausible."""
    bound = 1.2 * TORQUE_OFFSET_SHARE * _spans(data)[2]
    return np.linspace(-bound, bound, TORQUE_OFFSET_GRID)


def interpolation_periods(data: DesignData) -> np.ndarray:
    return np.array([data.signal_period_arcsec, data.signal_period_arcsec / 2.0])


def periodic_grid(data: DesignData) -> np.ndarray:
    """Periods for the free-period search: uniform in frequency, ≥ 1.5 cycles inside the angle span, clear of the
    signal period and its half (< 1 cycle apart within the span is the interpolation error)."""
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
    return periods[clear_of_signal_period(data, periods)]


def clear_of_signal_period(data: DesignData, periods: np.ndarray) -> np.ndarray:
    """Which ``periods`` a free-period error may take: more than ``PERIOD_EXCLUSION`` from the signal period and its
    half, and at least one cycle per angle span away from them (closer is the interpolation error)."""
    span = float(np.ptp(data.sim_angle_arcsec)) or 1.0
    periods = np.asarray(periods, dtype=float)
    keep = np.ones(len(periods), dtype=bool)
    for p in interpolation_periods(data):
        keep &= (np.abs(periods / p - 1.0) > PERIOD_EXCLUSION) & (np.abs(1.0 / periods - 1.0 / p) >= 1.0 / span)
    return keep


# ----------------------------------------------------------------------------------------------------------
# The built-in effects


@dataclass
class _TimeSkew(EffectDefinition):
    def columns(self, data: DesignData, nl: float | None = None, rows: np.ndarray | None = None) -> np.ndarray:
        return skew_shift(data, _value(nl, self.name), rows)[:, None]

    def parameters_from(self, coef: np.ndarray, nl: float | None) -> dict[str, float]:
        return {"skew_s": _value(nl, self.name)}

    def grid(self, data: DesignData) -> np.ndarray:
        return skew_grid(data)

    def unavailable(self, data: DesignData) -> str | None:
        if not data.has_time:
            return "needs time_s"
        if not np.any(np.diff(data.time_s) > 0):
            return "time_s does not increase"
        return None

    def implausible(self, params: Params, data: DesignData) -> str | None:
        if abs(params["skew_s"]) > MAX_SKEW_S:
            return f"skew {params['skew_s']:.3g} s exceeds {MAX_SKEW_S} s"
        return None

    def formula(self, signals: Signals, params: Params) -> np.ndarray:
        raise TypeError("time_skew is a re-evaluation in time: use signature() on a design or streaming()")

    def signature(self, data: DesignData, params: Params) -> np.ndarray:
        return skew_shift(data, params["skew_s"])

    def streaming(self, params: Params) -> Streaming:
        return _TorqueLag(float(params["skew_s"]))


@dataclass
class _TorqueLag:
    """The torque reading at t is the applied torque at t − τ (τ ≥ 0), carried across batches."""

    skew_s: float
    _hist_t: np.ndarray = field(default_factory=lambda: np.empty(0))
    _hist_torque: np.ndarray = field(default_factory=lambda: np.empty(0))

    def torque_signal_nm(self, time_s: np.ndarray, torque_signal_nm: np.ndarray) -> np.ndarray:
        if self.skew_s <= 0:
            return torque_signal_nm
        ht = np.concatenate((self._hist_t, time_s))
        hq = np.concatenate((self._hist_torque, torque_signal_nm))
        out = np.interp(time_s - self.skew_s, ht, hq)
        keep = ht >= time_s[-1] - self.skew_s - 1.0
        self._hist_t, self._hist_torque = ht[keep], hq[keep]
        return out

    def angle_arcsec(self, signals: Signals) -> np.ndarray:
        return np.zeros(len(signals.torque_nm))


@dataclass
class _TorqueOffset(EffectDefinition):
    """A zero offset of the torque reading: the simulation, driven by the reading, is the reducer T0 further
    along the torque axis (a re-evaluation of its history-free curve, with gain 1)."""

    def columns(self, data: DesignData, nl: float | None = None, rows: np.ndarray | None = None) -> np.ndarray:
        return torque_shift(data, _value(nl, self.name), rows)[:, None]

    def parameters_from(self, coef: np.ndarray, nl: float | None) -> dict[str, float]:
        return {"offset_nm": _value(nl, self.name)}

    def grid(self, data: DesignData) -> np.ndarray:
        return torque_offset_grid(data)

    def implausible(self, params: Params, data: DesignData) -> str | None:
        return _torque_offset_bound(params["offset_nm"], data)

    def formula(self, signals: Signals, params: Params) -> np.ndarray:
        raise TypeError("torque_zero_offset re-reads the simulated curve: use signature() on a design or streaming()")

    def signature(self, data: DesignData, params: Params) -> np.ndarray:
        return torque_shift(data, params["offset_nm"])

    def streaming(self, params: Params) -> Streaming:
        return _TorqueReadingOffset(float(params["offset_nm"]))


@dataclass
class _TorqueReadingOffset:
    """The torque reading is the applied torque plus T0 (the simulated bench's hidden torque zero offset)."""

    offset_nm: float

    def torque_signal_nm(self, time_s: np.ndarray, torque_signal_nm: np.ndarray) -> np.ndarray:
        return torque_signal_nm + self.offset_nm

    def angle_arcsec(self, signals: Signals) -> np.ndarray:
        return np.zeros(len(signals.torque_nm))


@dataclass
class _Periodic(EffectDefinition):
    """A·sin(2π·θ/P + ψ); the period is searched on a grid (the signal period and its half, or free)."""

    free_period: bool = False

    def columns(self, data: DesignData, nl: float | None = None, rows: np.ndarray | None = None) -> np.ndarray:
        theta = data.sim_angle_arcsec if rows is None else data.sim_angle_arcsec[rows]
        return sincos(theta, _value(nl, self.name))

    def parameters_from(self, coef: np.ndarray, nl: float | None) -> dict[str, float]:
        a, b = float(coef[0]), float(coef[1])  # a·sin x + b·cos x = A·sin(x + ψ)
        return {"period_arcsec": _value(nl, self.name), "amplitude_arcsec": math.hypot(a, b),
                "phase_rad": math.atan2(b, a)}

    def grid(self, data: DesignData) -> np.ndarray:
        return periodic_grid(data) if self.free_period else interpolation_periods(data)

    def unavailable(self, data: DesignData) -> str | None:
        if self.free_period and len(periodic_grid(data)) == 0:
            return "angle span too small for a period search"
        return None

    def implausible(self, params: Params, data: DesignData) -> str | None:
        amplitude, period = params["amplitude_arcsec"], params["period_arcsec"]
        if not self.free_period:
            return "interpolation amplitude above 5 % of the signal period" if amplitude > 0.05 * period else None
        if amplitude > min(10.0, 0.1 * period):
            return "periodic amplitude above 10 ″ or 10 % of its period"
        if period > _spans(data)[0] / 1.5:
            return "fewer than 1.5 periods inside the angle span"
        return None

    def identification_limit(self, params: Params, data: DesignData) -> str | None:
        if not self.free_period:
            return None
        cycles = float(np.ptp(data.sim_angle_arcsec)) / params["period_arcsec"]
        if cycles < MIN_IDENTIFIED_CYCLES:
            return (f"{cycles:.1f} cycles of its {params['period_arcsec']:.4g}″ period inside the angle span "
                    f"(< {MIN_IDENTIFIED_CYCLES}): it cannot be told from a smooth shape outside the catalogue")
        return None

    def formula(self, signals: Signals, params: Params) -> np.ndarray:
        x = 2.0 * math.pi * signals.sim_angle_arcsec / params["period_arcsec"] + params["phase_rad"]
        return params["amplitude_arcsec"] * np.sin(x)


def _fraction_of_span(what: str, power: int) -> Callable[[float, DesignData], str | None]:
    def bound(value: float, data: DesignData) -> str | None:
        span, tmax, _ = _spans(data)
        return f"{what} larger than 20 % of the angle span" if abs(value) * tmax ** power > 0.2 * span else None
    return bound


def _torque_offset_bound(value: float, data: DesignData) -> str | None:
    if abs(value) > TORQUE_OFFSET_SHARE * _spans(data)[2]:
        return f"torque offset above {TORQUE_OFFSET_SHARE:.0%} of the torque span"
    return None


def _scale_compensator(params: Params) -> Term:
    from tcms_daq.compensation.terms import Scale
    return Scale(coefficient=params["ratio"])


def _torsion_compensator(params: Params) -> Term:
    from tcms_daq.compensation.terms import Torsion
    return Torsion(arcsec_per_nm=params["coef_arcsec_per_nm"])


TIME_SKEW = register_effect(_TimeSkew(
    "time_skew", ("skew_s",), ("s",), "torque channel lags the angle: simulation taken at t + τ", "odd",
    f"|τ| ≤ {MAX_SKEW_S} s", rate_dependent=True, needs_time=True, nonlinear="skew_s", fixed_gain=True,
    typical={"skew_s": 0.02},
    kept_in_model="needs the torque trace (a time shift), not a function of (θ, T, t)"), built_in=True).name
THERMAL_DRIFT = register_effect(LinearEffect(
    "thermal_drift", ("rate_arcsec_per_s",), ("″/s",), "linear drift of the angle with time", "time",
    "|r| ≤ 0.1 ″/s", needs_time=True, typical={"rate_arcsec_per_s": 0.03},
    kept_in_model="time-dependent: the compensator's drift term sees the bench's absolute clock",
    column=lambda s: np.asarray(s.elapsed_s, dtype=float),
    bound=lambda v, d: f"drift {v:.3g} ″/s exceeds 0.1 ″/s" if abs(v) > 0.1 else None), built_in=True).name
BENDING_DEFORMATION = register_effect(LinearEffect(
    "bending_deformation", ("coef_arcsec_per_nm2",), ("″/(N·m)²",),
    "bending of the measuring point, even in torque (c·T²)", "even",
    "|c·T_max²| ≤ 20 % of the simulated angle span", typical={"coef_arcsec_per_nm2": 2.5e-6},
    kept_in_model="a property of the reducer and its loading, kept in the bench model",
    column=lambda s: np.asarray(s.torque_nm, dtype=float) ** 2, bound=_fraction_of_span("bending term", 2)),
    built_in=True).name
TORSION_OFFSET = register_effect(LinearEffect(
    "torsion_offset", ("coef_arcsec_per_nm",), ("″/N·m",), "shaft torsion between the measuring planes (c·T)",
    "even", "|c·T_max| ≤ 20 % of the simulated angle span", typical={"coef_arcsec_per_nm": 0.003},
    compensator=_torsion_compensator,
    column=lambda s: np.asarray(s.torque_nm, dtype=float), bound=_fraction_of_span("torsion term", 1)),
    built_in=True).name
SCALE_ERROR = register_effect(LinearEffect(
    "scale_error", ("ratio",), ("1",), "encoder/measuring-chain scale error (s·θ_sim)", "even", "|s| ≤ 0.1",
    typical={"ratio": 0.01}, compensator=_scale_compensator,
    column=lambda s: np.asarray(s.sim_angle_arcsec, dtype=float),
    bound=lambda v, d: f"scale ratio {v:.3g} exceeds 0.1" if abs(v) > 0.1 else None), built_in=True).name
INTERPOLATION_ERROR = register_effect(_Periodic(
    "interpolation_error", ("period_arcsec", "amplitude_arcsec", "phase_rad"), ("″", "″", "rad"),
    "encoder interpolation error at the signal period or its half", "even", "amplitude ≤ 5 % of the period",
    nonlinear="period_arcsec", grid_refine="discrete", sim_defaults={"period_arcsec": 72.0, "phase_rad": 0.0},
    typical={"period_arcsec": 72.0, "amplitude_arcsec": 0.6, "phase_rad": 0.5},
    kept_in_model="a function of the compensated angle; re-identify it with tcms calibrate"), built_in=True).name
PERIODIC_ERROR = register_effect(_Periodic(
    "periodic_error", ("period_arcsec", "amplitude_arcsec", "phase_rad"), ("″", "″", "rad"),
    "periodic error in the angle at a period found by search", "even",
    "amplitude ≤ 10 ″ and ≤ 10 % of the period; ≥ 1.5 periods inside the angle span", nonlinear="period_arcsec",
    grid_refine="frequency",
    sim_defaults={"period_arcsec": 100.0, "phase_rad": 0.0},
    typical={"period_arcsec": 110.0, "amplitude_arcsec": 0.8, "phase_rad": 1.0},
    kept_in_model="a function of the compensated angle; re-identify it with tcms calibrate", free_period=True),
    built_in=True).name
BACKLASH = register_effect(LinearEffect(
    "backlash", ("backlash_arcsec",), ("″",), "extra loop width ±b/2 by load direction", "odd", "|b| ≤ 120 ″",
    typical={"backlash_arcsec": 2.0}, kept_in_model="needs the load direction, not a function of (θ, T, t)",
    column=lambda s: -0.5 * np.asarray(s.direction, dtype=float),
    bound=lambda v, d: "backlash above 120 ″" if abs(v) > 120.0 else None), built_in=True).name
TORQUE_ZERO_OFFSET = register_effect(_TorqueOffset(
    "torque_zero_offset", ("offset_nm",), ("N·m",),
    "torque sensor zero offset: the simulated curve's history-free part read T0 along the torque axis "
    "(θ_hf(T − T0) − θ_hf(T))", "even", f"|T0| ≤ {TORQUE_OFFSET_SHARE:.0%} of the torque span",
    nonlinear="offset_nm", fixed_gain=True, typical={"offset_nm": 8.0},
    kept_in_model="needs the simulated curve along the torque axis, not a function of (θ, T, t)"),
    built_in=True).name
NONLINEAR_STIFFNESS = register_effect(LinearEffect(
    "nonlinear_stiffness", ("coef_arcsec_per_nm3",), ("″/(N·m)³",),
    "stiffness that changes with torque, odd in torque (c·T³)", "even",
    "|c·T_max³| ≤ 20 % of the simulated angle span", typical={"coef_arcsec_per_nm3": 2e-9},
    kept_in_model="a property of the reducer, kept in the bench model",
    column=lambda s: np.asarray(s.torque_nm, dtype=float) ** 3, bound=_fraction_of_span("cubic stiffness term", 3)),
    built_in=True).name

BUILT_IN = tuple(REGISTRY)

# A free-period periodic error in a one-directional design: which effect stands for "some other function of the
# torque" in the alias report.
ONE_TO_ONE_ALIAS = NONLINEAR_STIFFNESS

# What separates two look-alike effects (one sentence each).
SEPARATING: dict[frozenset[str], str] = {
    frozenset({TORSION_OFFSET, SCALE_ERROR}):
        "vary the lever arm or radial load independently of the torque, or move the measuring plane axially "
        "(or test a reducer of another stiffness): a scale error follows the angle, shaft torsion the torque",
    frozenset({BENDING_DEFORMATION, SCALE_ERROR}):
        "load in both directions through zero (±T): bending c·T² is even in torque, a scale error is odd",
    frozenset({BENDING_DEFORMATION, TORSION_OFFSET}):
        "load in both directions through zero (±T): c·T² is even in torque, c·T is odd",
    frozenset({TIME_SKEW, BACKLASH}):
        "repeat at a second loading rate (a skew grows with the rate, backlash does not) or check the channel "
        "timing with a hardware loopback",
    frozenset({PERIODIC_ERROR, NONLINEAR_STIFFNESS}):
        "load and unload (±T) and repeat with the encoder mounted at another angle (a coarse angle and half a "
        "signal period) with the reference recorded simultaneously: an error periodic in the encoder angle "
        "moves with the mounting angle, a torque-dependent difference (stiffness, seating, a separate "
        "reference run) does not",
    frozenset({TORQUE_ZERO_OFFSET, BACKLASH}):
        "tare at zero torque before and after and load symmetrically through zero",
    frozenset({BACKLASH, NONLINEAR_STIFFNESS}):
        "hold at the torque tips and load to two amplitudes: backlash is a constant width at every torque, a "
        "cubic stiffness grows with the amplitude",
    frozenset({INTERPOLATION_ERROR, PERIODIC_ERROR}):
        "extend the angle span (a larger torque amplitude) so the two periods drift apart by more than a cycle",
}

# The run that separates a pair, where a test request can make it (the separating sentences above say more):
# SECOND_RATE: the same test at its rate and at RATE_FACTOR × it; TIP_HOLDS: a stepped profile that holds at
# each step, the torque tips included. ``tcms_daq.discrepancy.stored.separating_request`` makes the request body.
SECOND_RATE = "second_rate"
TIP_HOLDS = "tip_holds"
SEPARATING_RUN: dict[frozenset[str], str] = {
    frozenset({TIME_SKEW, BACKLASH}): SECOND_RATE,
    frozenset({BACKLASH, NONLINEAR_STIFFNESS}): TIP_HOLDS,
}
SEPARATING_RUN_BY_MEMBER: tuple[tuple[frozenset[str], str], ...] = ((frozenset({TIME_SKEW}), SECOND_RATE),)

# The fallback sentence when a pair has no entry: by the kind of effect one member is.
SEPARATING_BY_MEMBER: tuple[tuple[frozenset[str], str], ...] = (
    (frozenset({THERMAL_DRIFT}),
     "record loading and unloading with zero-torque dwells at start and end and log the temperature: drift "
     "keeps growing with time while the torque goes back down"),
    (frozenset({INTERPOLATION_ERROR, PERIODIC_ERROR}),
     "repeat with the encoder mounting angle shifted by half a signal period and by a coarse angle: an "
     "encoder-periodic term moves with the mounting angle, a torque term does not"),
    (frozenset({TIME_SKEW}),
     "repeat at a second loading rate and with dwells: a skew vanishes in a dwell and grows with the rate"),
    (frozenset({TORQUE_ZERO_OFFSET}),
     "tare at zero torque before and after and load symmetrically through zero: a torque offset moves the curve "
     "along the torque axis, most in the lost-motion zone"),
)


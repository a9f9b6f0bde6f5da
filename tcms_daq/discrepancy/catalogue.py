"""The catalogue of named physical effects as the discrepancy workflow uses it: lookups by name over the one
registry of effects (:mod:`tcms_daq.discrepancy.effects`, where each effect is defined once, and where declared
effects are registered beside the built-in ones).

A constant offset is always fitted and is not an effect. Linear effects give columns whose coefficients are
the parameters; nonlinear ones (period, skew) also have a bounded grid that the workflow searches inside each
training fold and refines by parabolic interpolation. ``signature`` evaluates an effect from its parameters
(used to apply a model file to a simulation; the simulated bench streams the same formula).
"""

from __future__ import annotations

import numpy as np

from tcms_daq.discrepancy.design import DesignData
from tcms_daq.discrepancy.effects import (
    BUILT_IN,
    DECLARED,
    EFFECT_NAMES,
    ENTRY_POINT_GROUP,
    INTERPOLATION_ERROR,
    MAX_SKEW_S,
    MIN_IDENTIFIED_CYCLES,
    ONE_TO_ONE_ALIAS,
    PERIOD_EXCLUSION,
    REGISTRY,
    SEPARATING,
    SEPARATING_BY_MEMBER,
    SEPARATING_RUN,
    SEPARATING_RUN_BY_MEMBER,
    DeclaredEffect,
    EffectDefinition,
    clear_of_signal_period,
    interpolation_periods,
    load_entry_point_effects,
    periodic_grid,
    register_effect,
    sincos,
    skew_grid,
    skew_shift,
    unregister_effect,
)

Effect = EffectDefinition
CATALOGUE: dict[str, EffectDefinition] = REGISTRY  # the same mapping: registration shows here at once

__all__ = ["BUILT_IN", "CATALOGUE", "DECLARED", "EFFECT_NAMES", "ENTRY_POINT_GROUP", "INTERPOLATION_ERROR", "MAX_SKEW_S",
           "MIN_IDENTIFIED_CYCLES", "ONE_TO_ONE_ALIAS", "PERIOD_EXCLUSION", "DeclaredEffect", "Effect",
           "available", "clear_of_signal_period", "columns", "columns_at", "grid", "identification_limit", "interpolation_periods",
           "load_entry_point_effects", "parameters", "periodic_grid", "plausibility", "register_effect",
           "separating_experiment", "separating_run", "signature", "sincos", "skew_grid", "skew_shift", "unregister_effect"]


def grid(name: str, data: DesignData) -> np.ndarray | None:
    return REGISTRY[name].grid(data)


def columns(name: str, data: DesignData, nl: float | None = None) -> np.ndarray:
    """Design columns (n × m) of a linear effect, or the fixed-gain signature (n × 1) of a re-evaluation."""
    return REGISTRY[name].columns(data, nl)


def columns_at(name: str, data: DesignData, nl: float | None, rows: np.ndarray) -> np.ndarray:
    """``columns(name, data, nl)[rows]`` without evaluating the other rows where the effect can."""
    return REGISTRY[name].columns(data, nl, rows)


def parameters(name: str, coef: np.ndarray, nl: float | None) -> dict[str, float]:
    """Contract parameters from fitted coefficients (and the nonlinear value)."""
    return REGISTRY[name].parameters_from(coef, nl)


def signature(name: str, data: DesignData, params: dict[str, float]) -> np.ndarray:
    """The effect's contribution (″) to the simulated angle, from its contract parameters."""
    return REGISTRY[name].signature(data, params)


def identification_limit(name: str, params: dict[str, float], data: DesignData) -> str | None:
    """None if a fitted term is identified by its form, else why it may stand in for another shape."""
    return REGISTRY[name].identification_limit(params, data)


def plausibility(name: str, params: dict[str, float], data: DesignData) -> str | None:
    """None if the fitted value is physically plausible, else the reason in one line."""
    return REGISTRY[name].implausible(params, data)


def angle_follows_torque(data: DesignData) -> bool:
    """True when the design loads in one direction only: the angle is then a one-to-one function of the
    torque, and any error periodic in the angle is also some smooth function of the torque."""
    return bool(np.all(data.direction == data.direction[0]))




def cat_fixed_gain(name: str) -> bool:
    return CATALOGUE[name].fixed_gain


def available(name: str, data: DesignData) -> str | None:
    """None if the effect can be identified in this design at all, else why not (one line)."""
    eff = REGISTRY[name]
    reason = eff.unavailable(data)
    if reason is not None:
        return reason
    if eff.parity == "odd" and not eff.fixed_gain and np.all(data.direction == data.direction[0]):
        return "no load reversal in the data: a direction-odd term equals the constant offset"
    if eff.nonlinear:
        g = eff.grid(data)
        if g is None or len(g) == 0:
            return "no admissible values for its nonlinear parameter in this design"
        if eff.fixed_gain:
            return None
        cols = eff.columns(data, float(g[0]))
    else:
        cols = eff.columns(data)
    centred = cols - cols.mean(axis=0)
    if not np.any(np.abs(centred) > 1e-9 * (1.0 + np.abs(cols).max())):
        return "constant in this design (indistinguishable from the offset)"
    return None


def separating_experiment(names: list[str]) -> str:
    """The experiment that would tell the effects in ``names`` apart (one sentence per pair, no repeats)."""
    names = list(dict.fromkeys(names))
    found: list[str] = []
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            pair = frozenset({a, b})
            text = SEPARATING.get(pair)
            if text is None:
                text = next((t for members, t in SEPARATING_BY_MEMBER if pair & members),
                            "load in both directions at two rates and two encoder mounting angles")
            if text not in found:
                found.append(text)
    return "; ".join(found)


def separating_run(names: list[str]) -> str | None:
    """The kind of run that would separate the effects in ``names`` when a test request can make it
    (``effects.SECOND_RATE``, ``effects.TIP_HOLDS``), else None; the first pair that has one decides."""
    names = list(dict.fromkeys(names))
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            pair = frozenset({a, b})
            kind = SEPARATING_RUN.get(pair) or next(
                (k for members, k in SEPARATING_RUN_BY_MEMBER if pair & members), None)
            if kind is not None:
                return kind
    return None

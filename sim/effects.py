"""Switchable hidden effects of the simulated bench (all off by default): material for hidden-effect tests.

The effects are the discrepancy catalogue's (``tcms_daq.discrepancy.catalogue.CATALOGUE``: the one list of
effect names, parameters and units), in its forms, so the workflow can be checked to name them:

* ``time_skew`` (``skew_s`` ≥ 0): the torque signal lags the true torque by τ (the torque reading at t is the
  applied torque at t − τ), so a simulation driven by the reading is the true angle taken τ late.
* ``thermal_drift`` (``rate_arcsec_per_s``): r·t added to the angle signal.
* ``bending_deformation`` (``coef_arcsec_per_nm2``): c·T², ``torsion_offset`` (``coef_arcsec_per_nm``): c·T.
* ``scale_error`` (``ratio``): s·θ added to the angle signal.
* ``interpolation_error`` / ``periodic_error`` (``period_arcsec``, ``amplitude_arcsec``, ``phase_rad``):
  A·sin(2π·θ/P + ψ) of the angle signal.
* ``backlash`` (``backlash_arcsec``): −(b/2)·d with d = +1 while the applied torque rises, −1 while it falls.
* ``nonlinear_stiffness`` (``coef_arcsec_per_nm3``): c·T³.
* ``torque_zero_offset`` (``offset_nm``): the catalogue's first-order form −T0·dθ/dT, with dθ/dT the slope of
  the true twist along the trace (central differences of the noise-free signals). A physical zero offset of
  the torque reading is the bench's own ``torque_offset_nm``; on a history-dependent (hysteresis) model it
  moves only the history-free part of the curve, which a comparison of two traces cannot separate.

Configuration (bench TOML; an empty table or ``enabled = false`` switches an effect off)::

    [sim.effects.time_skew]
    skew_s = 0.02
    [sim.effects.interpolation_error]
    period_arcsec = 72.0
    amplitude_arcsec = 0.5
    phase_rad = 0.3

:func:`from_config` returns the bench hook (``SimulatedBench(effects=...)``): a stateful callable over
batches, so a run cut into batches gives the same result as in one piece.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from tcms_daq.discrepancy.catalogue import BUILT_IN, CATALOGUE
from tcms_daq.errors import ConfigError

# Defaults of parameters a [sim.effects] table may leave out (the others are required).
_DEFAULTS: dict[str, dict[str, float]] = {
    "interpolation_error": {"period_arcsec": 72.0, "phase_rad": 0.0},
    "periodic_error": {"period_arcsec": 100.0, "phase_rad": 0.0},
}


@dataclass(frozen=True)
class HiddenEffects:
    """The effects switched on: catalogue name → parameters, in the catalogue's names and units
    (``tcms_daq.discrepancy.catalogue.CATALOGUE``: one vocabulary for the simulator, the workflow and the
    model file). An effect whose primary parameter is 0 is off."""

    table: dict[str, dict[str, float]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for name, params in self.table.items():
            if name not in BUILT_IN:
                raise ConfigError(f"sim.effects: unknown effect {name!r} (the simulator has: {', '.join(BUILT_IN)})")
            unknown = set(params) - set(CATALOGUE[name].parameters)
            if unknown:
                raise ConfigError(f"sim.effects.{name}: unknown key {sorted(unknown)[0]!r} "
                                  f"(parameters: {', '.join(CATALOGUE[name].parameters)})")
            missing = [k for k in CATALOGUE[name].parameters if k not in params]
            if missing:
                raise ConfigError(f"sim.effects.{name}: missing parameter {missing[0]!r}")
        if self.value("time_skew", "skew_s") < 0:
            raise ConfigError(f"sim.effects.time_skew.skew_s must be >= 0 (a torque lag), got "
                              f"{self.value('time_skew', 'skew_s')}")
        for name in ("interpolation_error", "periodic_error"):
            if name in self.table and not self.table[name]["period_arcsec"] > 0:
                raise ConfigError(f"sim.effects.{name}.period_arcsec must be > 0, got "
                                  f"{self.table[name]['period_arcsec']}")

    def value(self, name: str, key: str) -> float:
        return float(self.table.get(name, {}).get(key, 0.0))

    @property
    def active(self) -> list[str]:
        """Names of the effects that are on (primary parameter ≠ 0: the amplitude of a periodic one)."""
        return [n for n, params in self.table.items()
                if params.get("amplitude_arcsec", params[CATALOGUE[n].parameters[0]]) != 0.0]


def effects_from_table(table: dict[str, Any]) -> HiddenEffects:
    """Parse a ``[sim.effects]`` table (catalogue names and parameters). Raises ConfigError (one line)."""
    parsed: dict[str, dict[str, float]] = {}
    for name, sub in (table or {}).items():
        if not isinstance(sub, dict):
            raise ConfigError(f"sim.effects.{name}: expected a table of parameters")
        sub = dict(sub)
        if not sub.pop("enabled", True):
            continue
        try:
            parsed[name] = {**_DEFAULTS.get(name, {}), **{k: float(v) for k, v in sub.items()}}
        except (TypeError, ValueError):
            raise ConfigError(f"sim.effects.{name}: parameters must be numbers") from None
    return HiddenEffects(parsed)


def effects_to_table(effects: HiddenEffects) -> dict[str, dict[str, float]]:
    """The ``[sim.effects]`` table of the active effects (inverse of :func:`effects_from_table`)."""
    return {name: dict(effects.table[name]) for name in effects.active}


@dataclass
class EffectsHook:
    """The bench's ``effects`` hook: changes the torque and angle signals of each batch (stateful)."""

    effects: HiddenEffects
    _hist_t: np.ndarray = field(default_factory=lambda: np.empty(0))
    _hist_torque: np.ndarray = field(default_factory=lambda: np.empty(0))
    _last_torque: float | None = None
    _direction: float = 1.0
    _last_slope: float = 0.0

    def __call__(self, cols: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        e = self.effects
        t = np.asarray(cols["time_s"], dtype=float)
        applied = np.asarray(cols["applied_torque_nm"], dtype=float)
        torque = np.asarray(cols["torque_signal_nm"], dtype=float).copy()
        angle = np.asarray(cols["angle_signal_arcsec"], dtype=float)
        if len(t) == 0:
            return cols
        skew_s = e.value("time_skew", "skew_s")
        if skew_s > 0:
            ht = np.concatenate((self._hist_t, t))
            hq = np.concatenate((self._hist_torque, torque))
            torque = np.interp(t - skew_s, ht, hq)
            keep = ht >= t[-1] - skew_s - 1.0
            self._hist_t, self._hist_torque = ht[keep], hq[keep]
        base = angle
        add = np.zeros_like(angle)
        add += e.value("scale_error", "ratio") * base
        add += e.value("thermal_drift", "rate_arcsec_per_s") * t
        add += e.value("bending_deformation", "coef_arcsec_per_nm2") * applied ** 2
        add += e.value("torsion_offset", "coef_arcsec_per_nm") * applied
        add += e.value("nonlinear_stiffness", "coef_arcsec_per_nm3") * applied ** 3
        for name in ("interpolation_error", "periodic_error"):
            if e.value(name, "amplitude_arcsec"):
                params = e.table[name]
                add += params["amplitude_arcsec"] * np.sin(2.0 * math.pi * base / params["period_arcsec"]
                                                           + params["phase_rad"])
        offset_nm = e.value("torque_zero_offset", "offset_nm")
        if offset_nm:
            add += -offset_nm * self._slope(applied, np.asarray(cols["true_angle_arcsec"], float))
        backlash_arcsec = e.value("backlash", "backlash_arcsec")
        if backlash_arcsec:
            add += -0.5 * backlash_arcsec * self._directions(applied)
        out = dict(cols)
        out["torque_signal_nm"] = torque
        out["angle_signal_arcsec"] = angle + add
        return out

    def _slope(self, torque: np.ndarray, angle: np.ndarray) -> np.ndarray:
        """dθ/dT along the trace by central differences (one-sided at the batch edges); flat stretches hold."""
        if len(torque) < 2:
            return np.full(len(torque), self._last_slope)
        dt_ = np.gradient(torque)
        da = np.gradient(angle)
        ok = np.abs(dt_) > 1e-9
        slope = np.where(ok, da / np.where(ok, dt_, 1.0), np.nan)
        if not ok.any():
            slope[:] = self._last_slope
        else:
            good = np.flatnonzero(ok)
            slope = np.interp(np.arange(len(slope)), good, slope[good])
        self._last_slope = float(slope[-1])
        return slope

    def _directions(self, applied: np.ndarray) -> np.ndarray:
        """+1 while the applied (noise-free) torque rises, −1 while it falls; held through flat stretches."""
        prev = applied[0] if self._last_torque is None else self._last_torque
        d = np.sign(np.diff(applied, prepend=prev))
        d[0] = d[0] or self._direction
        idx = np.where(d != 0, np.arange(len(d)), 0)
        np.maximum.accumulate(idx, out=idx)
        d = d[idx]
        self._last_torque = float(applied[-1])
        self._direction = float(d[-1])
        return d


def from_config(table: dict[str, Any], *, seed: int = 0) -> EffectsHook | None:
    """The bench hook for a ``[sim.effects]`` table, or None when every effect is off."""
    effects = effects_from_table(table)
    if not effects.active:
        return None
    return EffectsHook(effects)


__all__ = ["HiddenEffects", "EffectsHook", "effects_from_table", "effects_to_table", "from_config"]

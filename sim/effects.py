"""Switchable hidden effects of the simulated bench (all off by default): material for hidden-effect tests.

The effects use the forms of the discrepancy catalogue (``tcms_daq.discrepancy.catalogue``) and its contract
names and parameters, so the workflow can be checked to name them:

* ``time_skew`` (``skew_s`` ≥ 0): the torque signal lags the true torque by τ (the torque reading at t is the
  applied torque at t − τ), so a simulation driven by the reading is the true angle taken τ late.
* ``thermal_drift`` (``rate_arcsec_per_s``): r·t added to the angle signal.
* ``bending_deformation`` (``coef_arcsec_per_nm2``): c·T², ``torsion_offset`` (``coef_arcsec_per_nm``): c·T.
* ``scale_error`` (``ratio``): s·θ added to the angle signal.
* ``interpolation_error`` / ``periodic_error`` (``period_arcsec``, ``amplitude_arcsec``, ``phase_rad``):
  A·sin(2π·θ/P + ψ) of the angle signal.
* ``backlash`` (``backlash_arcsec``): −(b/2)·d with d = +1 while the applied torque rises, −1 while it falls.
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

from tcms_daq.errors import ConfigError


@dataclass(frozen=True)
class HiddenEffects:
    """Effect parameters in contract units; zero means off."""

    skew_s: float = 0.0
    drift_rate_arcsec_per_s: float = 0.0
    bending_coef_arcsec_per_nm2: float = 0.0
    torsion_coef_arcsec_per_nm: float = 0.0
    scale_ratio: float = 0.0
    interpolation: tuple[float, float, float] = (72.0, 0.0, 0.0)  # period, amplitude, phase
    periodic: tuple[float, float, float] = (100.0, 0.0, 0.0)
    backlash_arcsec: float = 0.0
    torque_zero_offset_nm: float = 0.0

    def __post_init__(self) -> None:
        if self.skew_s < 0:
            raise ConfigError(f"sim.effects.time_skew.skew_s must be >= 0 (a torque lag), got {self.skew_s}")
        for name, (period, _amp, _ph) in (("interpolation_error", self.interpolation),
                                          ("periodic_error", self.periodic)):
            if not period > 0:
                raise ConfigError(f"sim.effects.{name}.period_arcsec must be > 0, got {period}")

    @property
    def active(self) -> list[str]:
        """Contract names of the effects that are on."""
        on = {
            "time_skew": self.skew_s, "thermal_drift": self.drift_rate_arcsec_per_s,
            "bending_deformation": self.bending_coef_arcsec_per_nm2,
            "torsion_offset": self.torsion_coef_arcsec_per_nm, "scale_error": self.scale_ratio,
            "interpolation_error": self.interpolation[1], "periodic_error": self.periodic[1],
            "backlash": self.backlash_arcsec, "torque_zero_offset": self.torque_zero_offset_nm,
        }
        return [k for k, v in on.items() if v != 0.0]


_TABLE_KEYS: dict[str, tuple[str, ...]] = {
    "time_skew": ("skew_s",),
    "thermal_drift": ("rate_arcsec_per_s",),
    "bending_deformation": ("coef_arcsec_per_nm2",),
    "torsion_offset": ("coef_arcsec_per_nm",),
    "scale_error": ("ratio",),
    "interpolation_error": ("period_arcsec", "amplitude_arcsec", "phase_rad"),
    "periodic_error": ("period_arcsec", "amplitude_arcsec", "phase_rad"),
    "backlash": ("backlash_arcsec",),
    "torque_zero_offset": ("offset_nm",),
}


def effects_from_table(table: dict[str, Any]) -> HiddenEffects:
    """Parse a ``[sim.effects]`` table (contract names and parameters). Raises ConfigError (one line)."""
    kw: dict[str, Any] = {}
    for name, sub in (table or {}).items():
        if name not in _TABLE_KEYS:
            raise ConfigError(f"sim.effects: unknown effect {name!r} (known: {', '.join(_TABLE_KEYS)})")
        if not isinstance(sub, dict):
            raise ConfigError(f"sim.effects.{name}: expected a table of parameters")
        sub = dict(sub)
        if not sub.pop("enabled", True):
            continue
        unknown = set(sub) - set(_TABLE_KEYS[name])
        if unknown:
            raise ConfigError(f"sim.effects.{name}: unknown key {sorted(unknown)[0]!r}")
        try:
            vals = {k: float(v) for k, v in sub.items()}
        except (TypeError, ValueError):
            raise ConfigError(f"sim.effects.{name}: parameters must be numbers") from None
        if name in ("interpolation_error", "periodic_error"):
            default_period = 72.0 if name == "interpolation_error" else 100.0
            kw["interpolation" if name == "interpolation_error" else "periodic"] = (
                vals.get("period_arcsec", default_period), vals.get("amplitude_arcsec", 0.0),
                vals.get("phase_rad", 0.0))
            continue
        value = next(iter(vals.values()), 0.0)
        kw[{"time_skew": "skew_s", "thermal_drift": "drift_rate_arcsec_per_s",
            "bending_deformation": "bending_coef_arcsec_per_nm2", "torsion_offset": "torsion_coef_arcsec_per_nm",
            "scale_error": "scale_ratio", "backlash": "backlash_arcsec",
            "torque_zero_offset": "torque_zero_offset_nm"}[name]] = value
    return HiddenEffects(**kw)


def effects_to_table(effects: HiddenEffects) -> dict[str, dict[str, float]]:
    """The ``[sim.effects]`` table of the active effects (inverse of :func:`effects_from_table`)."""
    out: dict[str, dict[str, float]] = {}
    e = effects
    simple = {"time_skew": e.skew_s, "thermal_drift": e.drift_rate_arcsec_per_s,
              "bending_deformation": e.bending_coef_arcsec_per_nm2, "torsion_offset": e.torsion_coef_arcsec_per_nm,
              "scale_error": e.scale_ratio, "backlash": e.backlash_arcsec,
              "torque_zero_offset": e.torque_zero_offset_nm}
    for name, v in simple.items():
        if v != 0.0:
            out[name] = {_TABLE_KEYS[name][0]: float(v)}
    for name, (p, a, ph) in (("interpolation_error", e.interpolation), ("periodic_error", e.periodic)):
        if a != 0.0:
            out[name] = {"period_arcsec": p, "amplitude_arcsec": a, "phase_rad": ph}
    return out


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
        if e.skew_s > 0:
            ht = np.concatenate((self._hist_t, t))
            hq = np.concatenate((self._hist_torque, torque))
            torque = np.interp(t - e.skew_s, ht, hq)
            keep = ht >= t[-1] - e.skew_s - 1.0
            self._hist_t, self._hist_torque = ht[keep], hq[keep]
        base = angle
        add = np.zeros_like(angle)
        if e.scale_ratio:
            add += e.scale_ratio * base
        if e.drift_rate_arcsec_per_s:
            add += e.drift_rate_arcsec_per_s * t
        if e.bending_coef_arcsec_per_nm2:
            add += e.bending_coef_arcsec_per_nm2 * applied ** 2
        if e.torsion_coef_arcsec_per_nm:
            add += e.torsion_coef_arcsec_per_nm * applied
        for period, amp, phase in (e.interpolation, e.periodic):
            if amp:
                add += amp * np.sin(2.0 * math.pi * base / period + phase)
        if e.torque_zero_offset_nm:
            add += -e.torque_zero_offset_nm * self._slope(applied, np.asarray(cols["true_angle_arcsec"], float))
        if e.backlash_arcsec:
            add += -0.5 * e.backlash_arcsec * self._directions(applied)
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

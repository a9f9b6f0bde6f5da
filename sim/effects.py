"""Switchable hidden effects of the simulated bench (all off by default): material for hidden-effect tests.

The effects are the discrepancy workflow's, each defined once in ``tcms_daq.discrepancy.effects`` (its name,
parameters and units, its formula and its streaming form): this module only carries the signals the formulas read
across batches (the load direction of the applied torque, the slope dθ/dT of the true twist along the trace,
the elapsed time) and applies every active effect's streaming form to each batch. The torque is the applied
(noise-free) torque and the angle the angle signal before the effects; ``time_skew`` delays the torque reading
instead (the reading at t is the applied torque at t − τ), so a simulation driven by the reading is the true
angle taken τ late, and ``torque_zero_offset`` adds T0 to the torque reading (a simulation driven by the reading
runs T0 further along the torque axis) while the loader's drive is enabled: the amplifier's zero shifting with the
servo drive's switching, a common offset on real benches, which the procedure's tare (taken with the drive
disabled) cannot remove. (The bench's own ``torque_offset_nm`` is an offset at all times, which the tare removes.)

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

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from tcms_daq.discrepancy.effects import REGISTRY, TIME_SKEW, TORQUE_ZERO_OFFSET, BatchSignals, Streaming
from tcms_daq.errors import ConfigError

#: effects on the torque reading that act only while the loader's drive is enabled (its switching shifts the
#: amplifier's zero after the tare, which is taken with the drive disabled)
WHILE_DRIVE_ENABLED = frozenset({TORQUE_ZERO_OFFSET})


def _simulated() -> list[str]:
    return [name for name, effect in REGISTRY.items() if effect.simulated]


@dataclass(frozen=True)
class HiddenEffects:
    """The effects switched on: effect name → parameters, in the registry's names and units (one vocabulary for
    the simulator, the workflow and the model file). An effect whose primary parameter is 0 is off."""

    table: dict[str, dict[str, float]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for name, params in self.table.items():
            if name not in REGISTRY or not REGISTRY[name].simulated:
                raise ConfigError(f"sim.effects: unknown effect {name!r} (the simulator has: "
                                  f"{', '.join(_simulated())})")
            expected = REGISTRY[name].parameters
            unknown = set(params) - set(expected)
            if unknown:
                raise ConfigError(f"sim.effects.{name}: unknown key {sorted(unknown)[0]!r} "
                                  f"(parameters: {', '.join(expected)})")
            missing = [k for k in expected if k not in params]
            if missing:
                raise ConfigError(f"sim.effects.{name}: missing parameter {missing[0]!r}")
            if "period_arcsec" in params and not params["period_arcsec"] > 0:
                raise ConfigError(f"sim.effects.{name}.period_arcsec must be > 0, got {params['period_arcsec']}")
        if self.value(TIME_SKEW, "skew_s") < 0:
            raise ConfigError(f"sim.effects.{TIME_SKEW}.skew_s must be >= 0 (a torque lag), got "
                              f"{self.value(TIME_SKEW, 'skew_s')}")

    def value(self, name: str, key: str) -> float:
        return float(self.table.get(name, {}).get(key, 0.0))

    @property
    def active(self) -> list[str]:
        """Names of the effects that are on (primary parameter ≠ 0: the amplitude of a periodic one)."""
        return [n for n, params in self.table.items() if params[REGISTRY[n].primary] != 0.0]


def effects_from_table(table: dict[str, Any]) -> HiddenEffects:
    """Parse a ``[sim.effects]`` table (effect names and parameters). Raises ConfigError (one line)."""
    parsed: dict[str, dict[str, float]] = {}
    for name, sub in (table or {}).items():
        if not isinstance(sub, dict):
            raise ConfigError(f"sim.effects.{name}: expected a table of parameters")
        sub = dict(sub)
        if not sub.pop("enabled", True):
            continue
        defaults = REGISTRY[name].sim_defaults if name in REGISTRY else {}
        try:
            parsed[name] = {**defaults, **{k: float(v) for k, v in sub.items()}}
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
    _terms: list[tuple[str, Streaming]] = field(default_factory=list)
    _t0: float | None = None
    _last_torque: float | None = None
    _direction: float = 1.0
    _last_slope: float = 0.0

    def __post_init__(self) -> None:
        self._terms = [(n, REGISTRY[n].streaming(self.effects.table[n])) for n in self.effects.active]

    def __call__(self, cols: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        t = np.asarray(cols["time_s"], dtype=float)
        applied = np.asarray(cols["applied_torque_nm"], dtype=float)
        torque = np.asarray(cols["torque_signal_nm"], dtype=float).copy()
        angle = np.asarray(cols["angle_signal_arcsec"], dtype=float)
        if len(t) == 0:
            return cols
        if self._t0 is None:
            self._t0 = float(t[0])
        signals = BatchSignals(t - self._t0, applied, angle, self._directions(applied),
                               self._slope(applied, np.asarray(cols["true_angle_arcsec"], float)))
        enabled = np.asarray(cols.get("drive_enabled", np.ones(len(t), dtype=bool)), dtype=bool)
        add = np.zeros_like(angle)
        for name, term in self._terms:
            changed = term.torque_signal_nm(t, torque)
            torque = np.where(enabled, changed, torque) if name in WHILE_DRIVE_ENABLED else changed
            add += term.angle_arcsec(signals)
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


__all__ = ["WHILE_DRIVE_ENABLED", "HiddenEffects", "EffectsHook", "effects_from_table", "effects_to_table", "from_config"]

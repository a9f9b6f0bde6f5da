"""The richer reducer model of the simulated bench (``[sim] model = "rich"``): what a plant sees on a real RV.

On top of the simple forward model (``sim.physics``: elastic twist + lost-motion zone + Dahl friction) it adds

* **position dependence**: the elastic stiffness and the lost-motion zone vary with the output position φ (the
  angle the loader turned the output to): a once-per-revolution term (run-out, cumulative pin pitch error) and
  a term with the pin count z (cycloid/pin meshing), x(φ) = x₀·[1 + a₁·cos(φ − φ₁) + a_z·cos(z·φ − φ_z)];
* **asymmetric stiffness**: θ_el(T) scaled by (1 − a) for T > 0 and (1 + a) for T < 0 (stiffer positive);
* **creep and recovery**: a Kelvin–Voigt element, θ_cr' = (c_cr·T − θ_cr)/τ, c_cr = creep_share × the elastic
  compliance: under a held torque the twist creeps towards c_cr·T, at zero it recovers; a slow loop lets it
  follow (lower apparent rigidity), a fast one does not — the rigidity depends on the loading rate;
* **rate-dependent friction**: the Dahl law of ``sim.physics`` plus a viscous part −η·dT/dt (arcsec per
  N·m/s): the loop widens with the torque rate (rising branch lower, falling branch higher).

The twist of the output is then θ = θ_el,a(T; φ) + θ_lm(T; φ) + z_Dahl + θ_cr − η·Ṫ. Vectorised over a batch of
uniformly spaced samples with the state carried between batches, like ``sim.physics.twist_arcsec``. The
position is constant within a batch of a loaded test (moves happen at zero torque, where every position-dependent
term is zero). Its truth is computed numerically for a given test (``sim.truth``), not in closed form.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from tcms_daq.sim.drive import first_order_response
from tcms_daq.sim.physics import (
    ReducerPhysics,
    TwistState,
    elastic_twist_arcsec,
    hysteresis_arcsec,
    lost_motion_zone_arcsec,
)

from tcms_daq.config.models import RichReducerConfig


@dataclass(frozen=True)
class RichState:
    """History of the rich model: the Dahl state, the creep element's twist (arcsec), the last sample time (s)."""

    twist: TwistState = TwistState()
    creep_arcsec: float = 0.0
    time_s: float | None = None


def _variation(position_deg: float, pins: int, rev_pct: float, rev_phase_deg: float, pin_pct: float,
               pin_phase_deg: float) -> float:
    """1 + a₁·cos(φ − φ₁) + a_z·cos(z·φ − φ_z) at output position φ (degrees)."""
    return (1.0 + rev_pct / 100.0 * math.cos(math.radians(position_deg - rev_phase_deg))
            + pin_pct / 100.0 * math.cos(math.radians(pins * position_deg - pin_phase_deg)))


class RichReducerModel:
    """The rich forward model of one reducer: ``base`` (the catalogue-calibrated simple model at its mean) and
    the variations of ``config``."""

    def __init__(self, base: ReducerPhysics, config: RichReducerConfig | None = None):
        self.base = base
        self.config = config or RichReducerConfig()

    def physics_at(self, position_deg: float) -> ReducerPhysics:
        """The simple-model parameters at output position φ: stiffness and lost-motion zone varied."""
        c = self.config
        stiffness = _variation(position_deg, c.pins, c.stiffness_rev_pct, c.stiffness_rev_phase_deg,
                               c.stiffness_pin_pct, c.stiffness_pin_phase_deg)
        lost_motion = _variation(position_deg, c.pins, c.lost_motion_rev_pct, c.lost_motion_rev_phase_deg,
                                 c.lost_motion_pin_pct, c.lost_motion_pin_phase_deg)
        p = self.base
        hd = (None if p.hd_stiffness_nm_per_rad is None
              else tuple(k * stiffness for k in p.hd_stiffness_nm_per_rad))
        return replace(
            p,
            compliance_arcsec_per_nm=None if p.compliance_arcsec_per_nm is None else p.compliance_arcsec_per_nm / stiffness,
            hd_stiffness_nm_per_rad=hd,  # type: ignore[arg-type]
            lost_motion_zone_arcsec=p.lost_motion_zone_arcsec * lost_motion,
        )

    def creep_compliance_arcsec_per_nm(self, physics: ReducerPhysics) -> float:
        """c_cr: the creep element's compliance, creep_share × the elastic compliance at small torque."""
        small = 1e-3 * max(physics.lost_motion_zone_torque_nm, 1.0)
        return float(self.config.creep_share * elastic_twist_arcsec(small, physics) / small)

    def twist_arcsec(self, torque_nm: np.ndarray, time_s: np.ndarray, position_deg: float,
                     state: RichState | None = None) -> tuple[np.ndarray, RichState]:
        """Output twist (arcsec) along a torque trace (N·m) sampled at uniformly spaced ``time_s`` (s) at output
        position ``position_deg``; returns the twist and the state after the last sample."""
        state = state or RichState()
        t = np.asarray(torque_nm, dtype=float).ravel()
        times = np.asarray(time_s, dtype=float).ravel()
        if t.size == 0:
            return np.empty(0), state
        c = self.config
        physics = self.physics_at(position_deg)
        asym = c.asymmetry_pct / 100.0
        elastic = elastic_twist_arcsec(t, physics) * (1.0 - asym * np.sign(t))
        zone = lost_motion_zone_arcsec(t, physics)
        dahl, twist_state = hysteresis_arcsec(t, physics, state.twist)
        t_prev = state.time_s if state.time_s is not None else times[0] - (times[1] - times[0] if t.size > 1 else 1.0)
        dt = np.diff(times, prepend=t_prev)
        dt = np.where(dt > 0, dt, np.inf)
        rate = np.diff(t, prepend=state.twist.torque_nm) / dt
        viscous = -c.viscous_arcsec_per_nm_per_s * rate
        creep = self._creep(t, float(np.median(dt[np.isfinite(dt)])) if np.isfinite(dt).any() else 1.0,
                            physics, state.creep_arcsec)
        total = elastic + zone + dahl + creep + viscous
        return total, RichState(twist_state, float(creep[-1]), float(times[-1]))

    def _creep(self, torque_nm: np.ndarray, dt_s: float, physics: ReducerPhysics, creep_prev: float) -> np.ndarray:
        """The Kelvin–Voigt element over uniformly spaced samples (first-order response, exact for a torque held
        over each sample interval)."""
        c_cr = self.creep_compliance_arcsec_per_nm(physics)
        if c_cr == 0.0:
            return np.zeros_like(torque_nm)
        decay = dt_s / self.config.creep_time_s
        a = math.exp(-decay)
        return first_order_response((1.0 - a) * c_cr * torque_nm, a, creep_prev, decay)

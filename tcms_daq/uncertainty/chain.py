"""The measuring chain's input quantities: each a declared error of the readings, with estimate 0.

An :class:`Input` knows how its error enters the record (``apply``: the record with the error ``x`` added), so the
sensitivities come from the evaluation itself (``tcms_daq.uncertainty.budget``) and a Monte Carlo draw applies
all of them at once (``tcms_daq.uncertainty.montecarlo``). Conventions (the reading is the true value plus the
error): torque scale T·(1 + x), torque zero T + x, angle scale θ·(1 + x), absolute angle θ + x, interpolation
error x·sin(2πθ/P) and x·cos(2πθ/P) (an unknown phase: two inputs of the same u, reported as one line), the
compensation residual θ·(1 + x) and θ + x·T/1000, temperature x (K) through the declared coefficients.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from tcms_daq.config.models import ChainUncertainty

Arrays = tuple[np.ndarray, np.ndarray]  # (torque_nm, angle_arcsec)
Apply = Callable[[np.ndarray, np.ndarray, float], Arrays]


@dataclass(frozen=True)
class Input:
    """One Type B input quantity. ``u``: standard uncertainty in ``unit``; ``step``: the finite-difference step
    of its sensitivity (at least u, so the evaluation's discrete choices — windows, bracketing samples — do not
    dominate the difference); ``line``: the budget line it is reported on (the phase components of a periodic
    error share one)."""

    name: str
    unit: str
    u: float
    step: float
    apply: Apply
    line: str = ""

    @property
    def budget_line(self) -> str:
        return self.line or self.name


def _torque_scale(torque: np.ndarray, angle: np.ndarray, x: float) -> Arrays:
    return torque * (1.0 + x), angle


def _torque_zero(torque: np.ndarray, angle: np.ndarray, x: float) -> Arrays:
    return torque + x, angle


def _angle_scale(torque: np.ndarray, angle: np.ndarray, x: float) -> Arrays:
    return torque, angle * (1.0 + x)


def _angle_offset(torque: np.ndarray, angle: np.ndarray, x: float) -> Arrays:
    return torque, angle + x


def _periodic(period_arcsec: float, phase: Callable[[np.ndarray], np.ndarray]) -> Apply:
    def apply(torque: np.ndarray, angle: np.ndarray, x: float) -> Arrays:
        return torque, angle + x * phase(2.0 * math.pi * angle / period_arcsec)

    return apply


def _torsion(torque: np.ndarray, angle: np.ndarray, x: float) -> Arrays:
    return torque, angle + x * torque / 1000.0


def _temperature(t: ChainUncertainty) -> Apply:
    tc = t.temperature

    def apply(torque: np.ndarray, angle: np.ndarray, x: float) -> Arrays:
        return (torque * (1.0 + tc.torque_tc_rel_per_k * x) + tc.torque_zero_tc_nm_per_k * x,
                angle * (1.0 + tc.angle_tc_rel_per_k * x))

    return apply


def chain_inputs(chain: ChainUncertainty, test_torque_nm: float) -> list[Input]:
    """The declared inputs of a hysteresis test (sources with u = 0 are left out). ``test_torque_nm`` sizes the
    smallest finite-difference step of the torque zero (0.1 % of it)."""
    inputs: list[Input] = []

    def add(name: str, unit: str, u: float, min_step: float, apply: Apply, line: str = "") -> None:
        if u > 0.0:
            inputs.append(Input(name, unit, u, max(u, min_step), apply, line))

    add("torque scale", "1", chain.torque.u_rel, 1e-3, _torque_scale)
    add("torque zero", "N·m", chain.torque.u_zero_nm, 1e-3 * test_torque_nm, _torque_zero)
    add("angle scale", "1", chain.angle.u_rel, 1e-3, _angle_scale)
    add("angle absolute", "arcsec", chain.angle.u_arcsec, 0.1, _angle_offset)
    period = chain.angle.signal_period_arcsec
    line = f"interpolation error ({period:g}″ period)"
    add(f"{line}, sine", "arcsec", chain.angle.u_interpolation_arcsec, 0.1, _periodic(period, np.sin), line)
    add(f"{line}, cosine", "arcsec", chain.angle.u_interpolation_arcsec, 0.1, _periodic(period, np.cos), line)
    add("compensation scale residual", "1", chain.compensation.u_rel, 1e-3, _angle_scale)
    add("compensation torsion residual", "arcsec/kN·m", chain.compensation.u_torsion_arcsec_per_knm, 0.1, _torsion)
    if chain.temperature.declared():
        add("temperature", "K", chain.temperature.u_k, 0.1, _temperature(chain))
    return inputs

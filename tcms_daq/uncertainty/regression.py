"""Uncertainty of a least-squares fit whose residuals are correlated (a calibration series), JCGM 100 style.

Neighbouring points of a calibration series share slow errors, so the residuals are not independent and the
textbook s²(XᵀX)⁻¹ is too small. The errors are modelled as AR(1) in measurement order, correlation R_ij = ρ^|i−j|:
- ρ is the value for which the residuals of *this design* would show, on average, the lag-1 autocorrelation ρ₁
  measured (residuals of a fit are less correlated than the errors: the fit absorbs their slow part, the more so
  the more terms it has), i.e. ρ₁ = tr(S·M R(ρ) M)/tr(M R(ρ) M) with M = I − X(XᵀX)⁻¹Xᵀ and S the lag-1 pairing;
  ρ₁ < that of independent errors is taken as ρ = 0, never as a gain; half a standard error of ρ, √((1 − ρ²)/n)/2,
  is added (ρ is estimated from few points, and a low estimate would make U too small);
- the error variance σ² = rᵀr / tr(M R(ρ)) (unbiased under that model) and the coefficients' covariance the
  sandwich σ²·(XᵀX)⁻¹XᵀR(ρ)X(XᵀX)⁻¹;
- the degrees of freedom n_eff − p with n_eff = n(1 − ρ)/(1 + ρ), the effective number of observations.
On synthetic AR(1) residuals (tests/uncertainty/test_uncertainty_calibration_coverage.py) this U covers the true
coefficients in 93–98.5 % of draws for ρ from 0 to 0.8 (35 points, four coefficients).
A reference instrument's declared uncertainty (a common offset, a scale) enters exactly: the fit is linear, so
a reference error δ moves the coefficients by −(XᵀX)⁻¹Xᵀδ.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import brentq

from tcms_daq.config.models import ReferenceUncertainty
from tcms_daq.uncertainty.budget import Budget, Contribution, combine

MIN_DOF = 1.0
MAX_RHO = 0.99
RHO_ALLOWANCE = 0.5  # standard errors of ρ added to its estimate


@dataclass(frozen=True)
class ResidualCorrelation:
    """Lag-1 autocorrelation and Durbin–Watson statistic of the residuals; the AR(1) correlation ρ of the errors
    they imply and the effective number of observations n_eff (≤ n)."""

    lag1: float
    durbin_watson: float
    n: int
    n_eff: float
    rho: float = 0.0  # the errors' AR(1) correlation the residuals imply

    def to_dict(self) -> dict[str, float]:
        return {"lag1_autocorrelation": self.lag1, "durbin_watson": self.durbin_watson, "n": float(self.n),
                "n_eff": self.n_eff, "error_autocorrelation": self.rho}


def _ar1_correlation(n: int, rho: float) -> np.ndarray:
    lag = np.abs(np.arange(n)[:, None] - np.arange(n)[None, :])
    out: np.ndarray = np.power(rho, lag) if rho > 0.0 else (lag == 0).astype(float)
    return out


def _expected_residual_lag1(annihilator: np.ndarray, rho: float) -> float:
    """The lag-1 autocorrelation the residuals M·e of AR(1) errors e (correlation ρ) show on average."""
    mrm = annihilator @ _ar1_correlation(annihilator.shape[0], rho) @ annihilator
    return float(np.trace(mrm, offset=1) / np.trace(mrm))


def residual_correlation(residual: np.ndarray, design: np.ndarray) -> ResidualCorrelation:
    """ρ₁ (as measured), Durbin–Watson and n_eff = n(1 − ρ)/(1 + ρ) with ρ the AR(1) correlation of the errors that
    gives residuals of ``design`` the measured ρ₁ on average (n_eff at least p + MIN_DOF, so the degrees of freedom
    stay positive); ``rho`` is that ρ."""
    r = np.asarray(residual, dtype=float)
    n, p = design.shape
    ss = float(r @ r)
    if n < 3 or ss == 0.0:
        return ResidualCorrelation(0.0, 2.0, n, float(n), 0.0)
    lag1 = float(r[1:] @ r[:-1]) / ss
    dw = float(np.sum(np.diff(r) ** 2)) / ss
    m = np.eye(n) - design @ np.linalg.pinv(design)
    at_zero, at_max = _expected_residual_lag1(m, 0.0), _expected_residual_lag1(m, MAX_RHO)
    if lag1 <= at_zero:
        rho = 0.0
    elif lag1 >= at_max:
        rho = MAX_RHO
    else:
        rho = float(brentq(lambda q: _expected_residual_lag1(m, q) - lag1, 0.0, MAX_RHO, xtol=1e-6))
    # ρ is itself estimated, with standard error about √((1 − ρ²)/n): half of it is added, so a plug-in ρ that
    # happens to be low does not make U too small (the coverage test measures the effect)
    rho = min(rho + RHO_ALLOWANCE * math.sqrt((1.0 - rho * rho) / n), MAX_RHO)
    n_eff = max(n * (1.0 - rho) / (1.0 + rho), p + MIN_DOF)
    return ResidualCorrelation(lag1, dw, n, float(min(n_eff, n)), rho)


def coefficient_budgets(design: np.ndarray, residual: np.ndarray, reference_arcsec: np.ndarray,
                        coefficients: np.ndarray, names: list[str], units: list[str],
                        reference: ReferenceUncertainty | None) -> tuple[dict[str, Budget], ResidualCorrelation]:
    """A budget per fitted coefficient of y = X·β (y = encoder − reference, arcsec): Type A from the residuals
    with their autocorrelation, Type B from the reference instrument (a common offset ``u_arcsec``, a scale
    ``u_rel``)."""
    n, p = design.shape
    corr = residual_correlation(residual, design)
    xtx_inv = np.linalg.inv(design.T @ design)
    correlation = _ar1_correlation(n, corr.rho)
    annihilator = np.eye(n) - design @ xtx_inv @ design.T
    s2 = float(residual @ residual) / float(np.trace(annihilator @ correlation))
    u_a = np.sqrt(np.diag(s2 * xtx_inv @ design.T @ correlation @ design @ xtx_inv))
    dof = max(corr.n_eff - p, MIN_DOF)
    source = (f"fit residuals (n_eff = {corr.n_eff:.1f} of {n}, lag-1 autocorrelation {corr.lag1:.2f})")
    # the reading of the reference enters y with the sign −1: δβ = −(XᵀX)⁻¹Xᵀ δ_reference
    projector = xtx_inv @ design.T
    sens_offset = -projector @ np.ones(n)
    sens_scale = -projector @ reference_arcsec
    budgets = {}
    for j, name in enumerate(names):
        b_inputs = []
        if reference is not None and reference.u_arcsec > 0.0:
            b_inputs.append(Contribution("reference absolute", "arcsec", reference.u_arcsec, float(sens_offset[j])))
        if reference is not None and reference.u_rel > 0.0:
            b_inputs.append(Contribution("reference scale", "1", reference.u_rel, float(sens_scale[j])))
        budgets[name] = combine(float(coefficients[j]), units[j], float(u_a[j]), dof, source, b_inputs)
    return budgets, corr


def reading_budget(held_out_rms_arcsec: float, corr: ResidualCorrelation, n_parameters: int,
                   angle_arcsec: float, reference: ReferenceUncertainty | None) -> Budget:
    """The uncertainty of one compensated angle reading at ``angle_arcsec`` within the calibrated range: the
    held-out error of the fit (Type A, n_eff − p degrees of freedom) and the reference it is traced to."""
    b_inputs = []
    if reference is not None and reference.u_arcsec > 0.0:
        b_inputs.append(Contribution("reference absolute", "arcsec", reference.u_arcsec, 1.0))
    if reference is not None and reference.u_rel > 0.0:
        b_inputs.append(Contribution("reference scale", "1", reference.u_rel, float(angle_arcsec)))
    dof = max(corr.n_eff - n_parameters, MIN_DOF)
    return combine(0.0, "arcsec", held_out_rms_arcsec, dof, "held-out error of the fit (blocked CV)", b_inputs)

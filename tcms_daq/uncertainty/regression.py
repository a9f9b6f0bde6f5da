"""Uncertainty of a least-squares fit whose residuals are correlated (a calibration series), JCGM 100 style.

Neighbouring points of a calibration series share slow errors, so the residuals are not independent and the
textbook s²(XᵀX)⁻¹ is too small. With lag-1 autocorrelation ρ₁ of the residuals (in measurement order) the
effective number of observations is n_eff = n·(1 − ρ₁)/(1 + ρ₁) (the AR(1) variance inflation; ρ₁ < 0 is taken
as 0, never as a gain; ρ₁ corrected for its small-sample bias (1 + 3ρ₁)/n); the covariance is inflated by n/n_eff and the degrees of freedom are n_eff − p.
A reference instrument's declared uncertainty (a common offset, a scale) enters exactly: the fit is linear, so
a reference error δ moves the coefficients by −(XᵀX)⁻¹Xᵀδ.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tcms_daq.config.models import ReferenceUncertainty
from tcms_daq.uncertainty.budget import Budget, Contribution, combine

MIN_DOF = 1.0


@dataclass(frozen=True)
class ResidualCorrelation:
    """Lag-1 autocorrelation and Durbin–Watson statistic of the residuals; the effective number of
    observations n_eff (≤ n)."""

    lag1: float
    durbin_watson: float
    n: int
    n_eff: float

    def to_dict(self) -> dict[str, float]:
        return {"lag1_autocorrelation": self.lag1, "durbin_watson": self.durbin_watson, "n": float(self.n),
                "n_eff": self.n_eff}


def residual_correlation(residual: np.ndarray, n_parameters: int) -> ResidualCorrelation:
    """ρ₁ (as estimated), Durbin–Watson and n_eff = n(1 − ρ)/(1 + ρ) with ρ the bias-corrected ρ₁, of residuals in
    measurement order (n_eff at least p + MIN_DOF, so the degrees of freedom stay positive)."""
    r = np.asarray(residual, dtype=float)
    n = r.size
    ss = float(r @ r)
    if n < 3 or ss == 0.0:
        return ResidualCorrelation(0.0, 2.0, n, float(n))
    lag1 = float(r[1:] @ r[:-1]) / ss
    dw = float(np.sum(np.diff(r) ** 2)) / ss
    # the lag-1 estimate of a short series is biased low by about (1 + 3ρ)/n (Kendall): undo it for n_eff
    rho = min(max(lag1 + (1.0 + 3.0 * max(lag1, 0.0)) / n, 0.0), 0.99)
    n_eff = max(n * (1.0 - rho) / (1.0 + rho), n_parameters + MIN_DOF)
    return ResidualCorrelation(lag1, dw, n, float(min(n_eff, n)))


def coefficient_budgets(design: np.ndarray, residual: np.ndarray, reference_arcsec: np.ndarray,
                        coefficients: np.ndarray, names: list[str], units: list[str],
                        reference: ReferenceUncertainty | None) -> tuple[dict[str, Budget], ResidualCorrelation]:
    """A budget per fitted coefficient of y = X·β (y = encoder − reference, arcsec): Type A from the residuals
    with their autocorrelation, Type B from the reference instrument (a common offset ``u_arcsec``, a scale
    ``u_rel``)."""
    n, p = design.shape
    corr = residual_correlation(residual, p)
    xtx_inv = np.linalg.inv(design.T @ design)
    s2 = float(residual @ residual) / (n - p)
    u_a = np.sqrt(np.diag(s2 * xtx_inv) * n / corr.n_eff)
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

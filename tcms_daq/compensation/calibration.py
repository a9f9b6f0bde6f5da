"""Calibration of correction terms against a reference instrument (autocollimator), DESIGN §3 item 6.

Data: ``torque_nm, encoder_arcsec, reference_arcsec`` (+ optional ``time_s``), one row per point, in the order
measured. The encoder error y = encoder − reference is modelled as Σ term(encoder, torque, time) with the
terms' linear parameters fitted by ordinary least squares, so the compensated angle encoder − Σ term
approximates the reference. Reported:

* coefficients with their GUM budget (``tcms_daq.uncertainty.regression``): Type A from the residuals with their
  lag-1 autocorrelation (effective number of observations n_eff = n(1 − ρ₁)/(1 + ρ₁), n_eff − p degrees of
  freedom — never as if the points were independent), Type B from the reference instrument's declared
  uncertainty; expanded U with the t-based k for 95 %;
* before/after RMS and max of (angle − reference) on the calibration data (in-sample);
* held-out error: blocked cross-validation with contiguous blocks (the headline: neighbouring points of a series
  are correlated, so leave-one-out is optimistic) and leave-one-out (closed form r_i/(1 − h_ii)) beside it;
* the uncertainty of one compensated reading in the calibrated range: the blocked held-out error and the
  reference it is traced to.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from tcms_daq.compensation.compensator import Compensator
from tcms_daq.compensation.terms import Term, parse_term_spec
from tcms_daq.config.models import ReferenceUncertainty
from tcms_daq.crossval import contiguous_blocks, leave_one_group_out
from tcms_daq.errors import DataFormatError, EvaluationError
from tcms_daq.samples import read_csv_columns
from tcms_daq.uncertainty.budget import Budget
from tcms_daq.uncertainty.regression import ResidualCorrelation, coefficient_budgets, reading_budget

CALIBRATION_COLUMNS = ("torque_nm", "encoder_arcsec", "reference_arcsec")
DEFAULT_TERMS = ("offset", "scale")


@dataclass(frozen=True)
class CalibrationData:
    """Paired readings: torque (N·m), encoder and reference angle (arcsec), optional time (s)."""

    torque_nm: np.ndarray
    encoder_arcsec: np.ndarray
    reference_arcsec: np.ndarray
    time_s: np.ndarray | None = None
    source: str = "<data>"

    def __len__(self) -> int:
        return len(self.encoder_arcsec)


def read_calibration_csv(path: str | Path) -> CalibrationData:
    """Read a calibration CSV; DataFormatError (one line) for a missing file, column or bad value."""
    return _calibration_data(read_csv_columns(path, CALIBRATION_COLUMNS), str(path))


def _calibration_data(cols: dict[str, np.ndarray], source: str) -> CalibrationData:
    if len(cols["encoder_arcsec"]) == 0:
        raise DataFormatError(f"{source}: no data rows")
    return CalibrationData(cols["torque_nm"], cols["encoder_arcsec"], cols["reference_arcsec"], cols.get("time_s"),
                           source)


@dataclass
class TermFit:
    label: str
    term: Term
    values: dict[str, float]
    uncertainty: dict[str, float]  # expanded U (95 %, k of its budget)
    budgets: dict[str, Budget] = field(default_factory=dict)


@dataclass
class CalibrationResult:
    compensator: Compensator
    fits: list[TermFit]
    n: int
    rms_before_arcsec: float
    max_before_arcsec: float
    rms_after_arcsec: float
    max_after_arcsec: float
    loo_rms_arcsec: float
    loo_max_arcsec: float
    blocked_rms_arcsec: float
    blocked_max_arcsec: float
    n_blocks: int
    cv_method: str
    residual_after_arcsec: np.ndarray = field(repr=False)
    loo_residual_arcsec: np.ndarray = field(repr=False)
    blocked_residual_arcsec: np.ndarray = field(repr=False, default_factory=lambda: np.empty(0))  # NaN: not fitted
    correlation: ResidualCorrelation | None = None
    reading: Budget | None = None  # one compensated reading at the largest calibrated angle
    reading_angle_arcsec: float = 0.0
    reference: ReferenceUncertainty | None = None

    @property
    def cv_rms_arcsec(self) -> float:
        return self.loo_rms_arcsec if self.cv_method == "loo" else self.blocked_rms_arcsec

    @property
    def cv_max_arcsec(self) -> float:
        return self.loo_max_arcsec if self.cv_method == "loo" else self.blocked_max_arcsec

    def to_dict(self) -> dict[str, Any]:
        terms: dict[str, Any] = {}
        uncertainty: dict[str, Any] = {}
        for f in self.fits:
            for name, b in f.budgets.items():
                uncertainty[f"{f.label}.{name}"] = b.to_dict()
            if len(f.values) == 1:
                (name, value), = f.values.items()
                terms[f.label] = {"parameter": name, "value": value, "uncertainty": f.uncertainty[name],
                                  "k": f.budgets[name].k if name in f.budgets else None}
            else:
                terms[f.label] = {
                    "value": dict(f.values),
                    "uncertainty": dict(f.uncertainty),
                    "k": {name: b.k for name, b in f.budgets.items()},
                }
        if self.reading is not None:
            uncertainty["compensated_angle_arcsec"] = {**self.reading.to_dict(),
                                                       "at_angle_arcsec": self.reading_angle_arcsec}
        return {
            "n": self.n,
            "terms": terms,
            "uncertainty": uncertainty,
            "uncertainty_basis": ("declared reference: " + ", ".join(
                f"{k} {v:g}" for k, v in self.reference.model_dump().items() if v)
                if self.reference is not None and self.reference.declared() else
                "residuals only (no reference uncertainty declared)"),
            "residual_correlation": self.correlation.to_dict() if self.correlation is not None else None,
            "rms_before_arcsec": self.rms_before_arcsec,
            "max_before_arcsec": self.max_before_arcsec,
            "rms_after_arcsec": self.rms_after_arcsec,
            "max_after_arcsec": self.max_after_arcsec,
            "cv_method": self.cv_method,
            "cv_rms_arcsec": self.cv_rms_arcsec,
            "cv_max_arcsec": self.cv_max_arcsec,
            "loo_rms_arcsec": self.loo_rms_arcsec,
            "loo_max_arcsec": self.loo_max_arcsec,
            "blocked_cv_rms_arcsec": self.blocked_rms_arcsec,
            "blocked_cv_max_arcsec": self.blocked_max_arcsec,
            "blocked_cv_blocks": self.n_blocks,
        }


def _parameter_unit(name: str) -> str:
    """The unit of a linear parameter from its name (value_arcsec, coefficient, arcsec_per_nm …)."""
    if "_per_" in name:
        head, _, tail = name.partition("_per_")
        return f"{head}/{ {'nm': 'N·m', 's': 's'}.get(tail, tail)}"
    return "arcsec" if name.endswith("arcsec") else "1"


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x)))) if x.size else float("nan")


def _maxabs(x: np.ndarray) -> float:
    return float(np.max(np.abs(x))) if x.size else float("nan")


def _resolve_terms(terms: Sequence[Term | str]) -> list[Term]:
    out = [parse_term_spec(t) if isinstance(t, str) else t for t in terms]
    if not out:
        raise EvaluationError("no terms to calibrate")
    labels = [t.label() for t in out]
    dup = next((lab for lab in labels if labels.count(lab) > 1), None)
    if dup:
        raise EvaluationError(f"term {dup!r} given twice")
    return out


def design_matrix(terms: Sequence[Term], data: CalibrationData) -> tuple[np.ndarray, list[tuple[int, str]]]:
    """Columns of all linear parameters; the index list maps column → (term index, parameter name)."""
    cols: list[np.ndarray] = []
    index: list[tuple[int, str]] = []
    for i, term in enumerate(terms):
        if term.time_dependent and data.time_s is None:
            raise DataFormatError(f"{data.source}: term {term.label()!r} needs a 'time_s' column")
        block = np.asarray(term.design_columns(data.encoder_arcsec, data.torque_nm, data.time_s), dtype=float)
        if block.ndim != 2 or block.shape != (len(data), len(term.linear_params)):
            raise EvaluationError(f"term {term.label()!r} returned design columns of shape {block.shape}")
        cols.append(block)
        index.extend((i, p) for p in term.linear_params)
    return np.hstack(cols), index


def calibrate(
    data: CalibrationData,
    terms: Sequence[Term | str] = DEFAULT_TERMS,
    *,
    blocks: int = 5,
    cv: str = "auto",
    reference: ReferenceUncertainty | None = None,
) -> CalibrationResult:
    """Fit the linear parameters of ``terms`` (Term objects or names such as "offset", "periodic:72").

    cv: the headline held-out error: "blocked" (contiguous blocks; "auto" means it: rows are in the order
    measured) or "loo". reference: the reference instrument's declared standard uncertainty (None: not
    declared). Raises EvaluationError if the terms are not identifiable from the data or too few points remain.
    """
    if cv not in ("auto", "loo", "blocked"):
        raise EvaluationError(f"unknown cross-validation {cv!r} (loo, blocked, auto)")
    term_list = _resolve_terms(terms)
    x, index = design_matrix(term_list, data)
    y = data.encoder_arcsec - data.reference_arcsec
    n, p = x.shape
    if n <= p + 1:
        raise EvaluationError(f"{data.source}: {n} points are too few to fit {p} parameters with held-out error")
    # scale the columns so the rank test is about collinearity, not units
    norms = np.linalg.norm(x, axis=0)
    norms[norms == 0] = 1.0
    xs = x / norms
    q, r = np.linalg.qr(xs)
    sv = np.linalg.svd(r, compute_uv=False)
    if sv[-1] <= 1e-10 * sv[0]:
        raise EvaluationError(
            f"{data.source}: the terms {', '.join(t.label() for t in term_list)} are not identifiable from these "
            "data (collinear columns)"
        )
    beta = np.linalg.solve(r, q.T @ y) / norms
    resid = y - x @ beta
    param_names = [f"{ti}:{name}" for ti, name in index]
    budgets, correlation = coefficient_budgets(x, resid, data.reference_arcsec, beta, param_names,
                                               [_parameter_unit(name) for _, name in index], reference)
    u_exp = np.array([budgets[name].expanded for name in param_names])

    hat = np.sum(q * q, axis=1)
    loo = resid / np.clip(1.0 - hat, 1e-12, None)

    k = max(2, min(int(blocks), n // max(p + 1, 2)))
    blocked = np.empty(n)
    for train, test in leave_one_group_out(np.arange(n), contiguous_blocks(n, k)):
        if np.linalg.matrix_rank(xs[train]) < p:
            blocked[test] = np.nan  # this fold cannot identify every term (e.g. a period not covered)
            continue
        coef = np.linalg.lstsq(x[train], y[train], rcond=None)[0]
        blocked[test] = y[test] - x[test] @ coef
    blocked_ok = blocked[np.isfinite(blocked)]

    fits, fitted_terms, uncs = [], [], []
    for i, term in enumerate(term_list):
        vals = {name: float(beta[j]) for j, (ti, name) in enumerate(index) if ti == i}
        us = {name: float(u_exp[j]) for j, (ti, name) in enumerate(index) if ti == i}
        bs = {name: budgets[param_names[j]] for j, (ti, name) in enumerate(index) if ti == i}
        fitted = term.with_params(**vals)
        fits.append(TermFit(term.label(), fitted, vals, us, bs))
        fitted_terms.append(fitted)
        uncs.append(us)
    comp = Compensator(
        fitted_terms,
        uncertainties=uncs,
        meta={"description": f"calibrated against a reference ({', '.join(t.label() for t in term_list)})",
              "source": data.source, "n_points": n},
    )
    method = "loo" if cv == "loo" else "blocked"
    held_out = _rms(loo) if method == "loo" else _rms(blocked_ok)
    reading_angle = float(np.max(np.abs(data.reference_arcsec)))
    reading = reading_budget(held_out, correlation, p, reading_angle, reference)
    return CalibrationResult(
        compensator=comp,
        fits=fits,
        n=n,
        rms_before_arcsec=_rms(y),
        max_before_arcsec=_maxabs(y),
        rms_after_arcsec=_rms(resid),
        max_after_arcsec=_maxabs(resid),
        loo_rms_arcsec=_rms(loo),
        loo_max_arcsec=_maxabs(loo),
        blocked_rms_arcsec=_rms(blocked_ok),
        blocked_max_arcsec=_maxabs(blocked_ok),
        n_blocks=k,
        cv_method=method,
        residual_after_arcsec=resid,
        loo_residual_arcsec=loo,
        blocked_residual_arcsec=blocked,
        correlation=correlation,
        reading=reading,
        reading_angle_arcsec=reading_angle,
        reference=reference,
    )


def format_calibration(result: CalibrationResult) -> str:
    from tcms_daq.analysis.rounding import with_uncertainty

    corr = result.correlation
    lines = [f"calibration on {result.n} points (expanded uncertainties U for 95 %, k from the effective degrees "
             "of freedom)"]
    if corr is not None:
        lines.append(f"  residuals: lag-1 autocorrelation {corr.lag1:.2f}, Durbin–Watson {corr.durbin_watson:.2f}, "
                     f"n_eff {corr.n_eff:.1f} of {corr.n}")
    for f in result.fits:
        for name, value in f.values.items():
            b = f.budgets.get(name)
            shown = with_uncertainty(value, b.to_dict() if b else None, "")
            lines.append(f"  {f.label:<14} {name:<16} {shown}" + (f"  dominant: {b.dominant}" if b else ""))
    lines.append(f"  before:  rms {result.rms_before_arcsec:.3f}″  max {result.max_before_arcsec:.3f}″")
    lines.append(f"  after:   rms {result.rms_after_arcsec:.3f}″  max {result.max_after_arcsec:.3f}″ (in-sample)")
    lines.append(
        f"  held out (blocked, {result.n_blocks} contiguous blocks): rms {result.blocked_rms_arcsec:.3f}″  "
        f"max {result.blocked_max_arcsec:.3f}″" + ("  (headline)" if result.cv_method == "blocked" else "")
    )
    lines.append(f"  held out (leave-one-out, optimistic for correlated residuals): rms {result.loo_rms_arcsec:.3f}″"
                 f"  max {result.loo_max_arcsec:.3f}″")
    if result.reading is not None:
        lines.append(f"  one compensated reading (up to {result.reading_angle_arcsec:.4g}″): ± "
                     f"{with_uncertainty(0.0, result.reading.to_dict(), 'arcsec').split('± ')[1]}; "
                     f"dominant: {result.reading.dominant}")
    return "\n".join(lines)

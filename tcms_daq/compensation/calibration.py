"""Calibration of correction terms against a reference instrument (autocollimator), DESIGN §3 item 6.

Data: ``torque_nm, encoder_arcsec, reference_arcsec`` (+ optional ``time_s``), one row per point, in the order
measured. The encoder error y = encoder − reference is modelled as Σ term(encoder, torque, time) with the
terms' linear parameters fitted by ordinary least squares, so the compensated angle encoder − Σ term
approximates the reference. Reported:

* coefficients with expanded uncertainty U = 2·u (coverage factor k = 2; u from s²(XᵀX)⁻¹, s² = RSS/(n − p));
* before/after RMS and max of (angle − reference) on the calibration data (in-sample);
* held-out error: leave-one-out (closed form r_i/(1 − h_ii)) and blocked cross-validation with contiguous
  blocks (for series, where neighbouring points are correlated and LOO is optimistic).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from tcms_daq.compensation.compensator import Compensator
from tcms_daq.compensation.terms import Term, parse_term_spec
from tcms_daq.crossval import contiguous_blocks, leave_one_group_out
from tcms_daq.errors import DataFormatError, EvaluationError
from tcms_daq.samples import read_csv_columns

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
    uncertainty: dict[str, float]  # expanded, k = 2


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

    @property
    def cv_rms_arcsec(self) -> float:
        return self.loo_rms_arcsec if self.cv_method == "loo" else self.blocked_rms_arcsec

    @property
    def cv_max_arcsec(self) -> float:
        return self.loo_max_arcsec if self.cv_method == "loo" else self.blocked_max_arcsec

    def to_dict(self) -> dict[str, Any]:
        terms: dict[str, Any] = {}
        for f in self.fits:
            if len(f.values) == 1:
                (name, value), = f.values.items()
                terms[f.label] = {"parameter": name, "value": value, "uncertainty": f.uncertainty[name]}
            else:
                terms[f.label] = {
                    "value": dict(f.values),
                    "uncertainty": dict(f.uncertainty),
                }
        return {
            "n": self.n,
            "terms": terms,
            "uncertainty_coverage_factor": 2,
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
) -> CalibrationResult:
    """Fit the linear parameters of ``terms`` (Term objects or names such as "offset", "periodic:72").

    cv: "loo", "blocked" or "auto" (blocked when the data have a time_s column, i.e. are a series).
    Raises EvaluationError if the terms are not identifiable from the data or too few points remain.
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
    dof = n - p
    s2 = float(resid @ resid) / dof
    rinv = np.linalg.inv(r)
    cov = s2 * (rinv @ rinv.T) / np.outer(norms, norms)
    u_exp = 2.0 * np.sqrt(np.diag(cov))

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
        fitted = term.with_params(**vals)
        fits.append(TermFit(term.label(), fitted, vals, us))
        fitted_terms.append(fitted)
        uncs.append(us)
    comp = Compensator(
        fitted_terms,
        uncertainties=uncs,
        meta={"description": f"calibrated against a reference ({', '.join(t.label() for t in term_list)})",
              "source": data.source, "n_points": n},
    )
    method = cv if cv != "auto" else ("blocked" if data.time_s is not None else "loo")
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
    )


def format_calibration(result: CalibrationResult) -> str:
    lines = [f"calibration on {result.n} points (uncertainties expanded, k = 2)"]
    for f in result.fits:
        for name, value in f.values.items():
            lines.append(f"  {f.label:<14} {name:<16} {value:+.6g} ± {f.uncertainty[name]:.2g}")
    lines.append(f"  before:  rms {result.rms_before_arcsec:.3f}″  max {result.max_before_arcsec:.3f}″")
    lines.append(f"  after:   rms {result.rms_after_arcsec:.3f}″  max {result.max_after_arcsec:.3f}″ (in-sample)")
    lines.append(f"  held out (leave-one-out): rms {result.loo_rms_arcsec:.3f}″  max {result.loo_max_arcsec:.3f}″")
    lines.append(
        f"  held out (blocked, {result.n_blocks} contiguous blocks): rms {result.blocked_rms_arcsec:.3f}″  "
        f"max {result.blocked_max_arcsec:.3f}″"
    )
    return "\n".join(lines)

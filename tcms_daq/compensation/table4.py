"""The paper's Table 4 (autocollimator vs encoder, 35 torque steps) and the reproducible comparison behind
``tcms table4`` and ``docs/table4.md``.

Every error here is (angle − autocollimator) in arcsec over the 35 points: the raw encoder, the paper's
"After Compensation" column, θ/1.03, the geometric model's prediction from Tables 2–3 (consistent form, and
the printed Eqs. 15/16 taken literally), and our calibrated fits with held-out error: blocked cross-validation
(5 contiguous blocks; the headline, since neighbouring points are correlated) and leave-one-out beside it, and
the coefficients' expanded uncertainty with the residuals' autocorrelation and the autocollimator's 0.2″.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, replace
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from tcms_daq.analysis.rounding import round_to_uncertainty
from tcms_daq.compensation.calibration import CALIBRATION_COLUMNS, CalibrationData, calibrate
from tcms_daq.compensation.geometry import evaluate_geometry, load_geometry
from tcms_daq.config.models import ReferenceUncertainty
from tcms_daq.samples import parse_csv_text

DATA_PACKAGE = "tcms_daq.compensation"
CSV_NAME = "data/paper_table4.csv"
PROVENANCE_NAME = "data/paper_table4.toml"
PAPER_TEXT_MAX_BEFORE_ARCSEC = 10.9
PAPER_TEXT_MAX_AFTER_ARCSEC = 2.1
PAPER_TEXT_PERCENT_BEFORE = 3.7
PAPER_TEXT_PERCENT_AFTER = 0.7
PAPER_FACTOR = 1.03
# the autocollimator: "accuracy 0.2 arcsec" (paper_table4.toml), taken as its standard uncertainty (a common
# offset of its readings; conservative if the figure is a bound)
REFERENCE_U_ARCSEC = 0.2
CV_BLOCKS = 5


@dataclass(frozen=True)
class Table4:
    torque_nm: np.ndarray
    reference_arcsec: np.ndarray
    encoder_arcsec: np.ndarray
    paper_compensated_arcsec: np.ndarray
    provenance: dict[str, Any]

    def calibration_data(self) -> CalibrationData:
        return CalibrationData(self.torque_nm, self.encoder_arcsec, self.reference_arcsec, None, "paper Table 4")


def load_table4() -> Table4:
    """The transcribed Table 4 shipped with the package, with its provenance."""
    base = resources.files(DATA_PACKAGE)
    text = base.joinpath(CSV_NAME).read_text(encoding="utf-8")
    cols = parse_csv_text(text, required=(*CALIBRATION_COLUMNS, "paper_compensated_arcsec"), source="paper_table4.csv")
    prov = tomllib.loads(base.joinpath(PROVENANCE_NAME).read_text(encoding="utf-8"))
    return Table4(cols["torque_nm"], cols["reference_arcsec"], cols["encoder_arcsec"], cols["paper_compensated_arcsec"],
                  prov)


def default_geometry_path() -> Path:
    """The paper's geometry (Tables 2 and 3), packaged as ``geometry-paper.toml``."""
    return Path(str(resources.files("tcms_daq.defaults").joinpath("geometry-paper.toml")))


def error_stats(angle_arcsec: np.ndarray, reference_arcsec: np.ndarray) -> dict[str, float]:
    """RMS, max |·| and mean of (angle − reference), and the mean relative error |·|/reference in % over the
    points with reference > 1″ (the zero-torque point has no meaningful ratio)."""
    r = np.asarray(angle_arcsec, dtype=float) - reference_arcsec
    mask = reference_arcsec > 1.0
    return {
        "rms_arcsec": float(np.sqrt(np.mean(r * r))),
        "max_arcsec": float(np.max(np.abs(r))),
        "mean_arcsec": float(np.mean(r)),
        "mean_relative_percent": float(np.mean(np.abs(r[mask]) / reference_arcsec[mask]) * 100.0),
    }


def _row(key: str, label: str, kind: str, angle: np.ndarray, ref: np.ndarray, **extra: Any) -> dict[str, Any]:
    return {"key": key, "label": label, "kind": kind, **error_stats(angle, ref), **extra}


def table4_comparison(geometry_path: str | Path | None = None) -> dict[str, Any]:
    """All numbers of the comparison page (see the module docstring)."""
    t4 = load_table4()
    geometry_path = Path(geometry_path) if geometry_path is not None else default_geometry_path()
    geom = load_geometry(geometry_path)
    model = evaluate_geometry(geom)
    ref, enc, torque = t4.reference_arcsec, t4.encoder_arcsec, t4.torque_nm
    rows: list[dict[str, Any]] = []
    rows.append(_row("raw", "raw encoder (uncompensated)", "measured", enc, ref))
    rows.append(_row("paper", "paper's 'After Compensation' column", "paper", t4.paper_compensated_arcsec, ref))
    rows.append(_row("paper_1_03", "encoder / 1.03 (the paper's column reproduced)", "paper", enc / PAPER_FACTOR, ref))

    slope = model.torsion_arcsec_per_nm
    sigma = geom.sigma
    rows.append(
        _row("model_full", f"geometric model (sigma = {sigma:+d}): k·θ − torsion", "prediction",
             model.k * enc - slope * torque, ref)
    )
    rows.append(_row("model_scale", f"geometric model (sigma = {sigma:+d}): scale k only", "prediction", model.k * enc, ref))
    rows.append(
        _row("model_torsion", f"geometric model (sigma = {sigma:+d}): torsion only", "prediction", enc - slope * torque, ref)
    )
    other = evaluate_geometry(replace(geom, sigma=-sigma))
    rows.append(
        _row("model_other_sign", f"geometric model (sigma = {-sigma:+d}): k·θ − torsion", "prediction",
             other.k * enc - other.torsion_arcsec_per_nm * torque, ref)
    )
    lit = model.literal
    if lit.k is not None and lit.eq16_bracket is not None:
        lit_slope = slope / model.delta_l_mm * lit.eq16_bracket if model.delta_l_mm else 0.0
        rows.append(
            _row("printed_eq16", "printed Eqs. 15/16 taken literally (dimensionally inconsistent)", "prediction",
                 lit.k * enc - lit_slope * torque, ref)
        )

    data = t4.calibration_data()
    fits = {}
    reference = ReferenceUncertainty(u_arcsec=REFERENCE_U_ARCSEC)
    for key, terms in (("scale", ("scale",)), ("offset_scale", ("offset", "scale"))):
        res = calibrate(data, terms, cv="blocked", blocks=CV_BLOCKS, reference=reference)
        fits[key] = res
        label = " + ".join(terms)
        rows.append(_row(f"fit_{key}", f"calibrated {label}, in-sample", "fit", ref + res.residual_after_arcsec, ref))
        rows.append(_row(f"fit_{key}_blocked", f"calibrated {label}, held out ({res.n_blocks} contiguous blocks)",
                         "held-out", ref + res.blocked_residual_arcsec, ref))
        rows.append(_row(f"fit_{key}_loo", f"calibrated {label}, held out (leave-one-out; optimistic here)",
                         "held-out", ref + res.loo_residual_arcsec, ref))

    ratio = t4.paper_compensated_arcsec[1:] / enc[1:]
    ls_scale = float(enc @ t4.paper_compensated_arcsec / (enc @ enc))
    dev = t4.paper_compensated_arcsec - enc / PAPER_FACTOR
    raw = rows[0]
    paper = rows[1]
    return {
        "source": {
            "table": t4.provenance.get("provenance", {}).get("location"),
            "paper": t4.provenance.get("provenance", {}).get("title"),
            "n_points": int(enc.size),
            "geometry": str(geometry_path),
        },
        "rows": rows,
        "paper_column": {
            "ls_scale_vs_encoder": ls_scale,
            "ratio_min": float(ratio.min()),
            "ratio_max": float(ratio.max()),
            "one_over_1_03": 1.0 / PAPER_FACTOR,
            "max_abs_difference_from_encoder_over_1_03_arcsec": float(np.max(np.abs(dev))),
        },
        "paper_text_claims": {
            "max_before_arcsec": PAPER_TEXT_MAX_BEFORE_ARCSEC,
            "max_after_arcsec": PAPER_TEXT_MAX_AFTER_ARCSEC,
            "percent_before": PAPER_TEXT_PERCENT_BEFORE,
            "percent_after": PAPER_TEXT_PERCENT_AFTER,
            "table_max_before_arcsec": raw["max_arcsec"],
            "table_max_after_arcsec": paper["max_arcsec"],
            "table_rms_before_arcsec": raw["rms_arcsec"],
            "table_rms_after_arcsec": paper["rms_arcsec"],
            "match": bool(
                abs(raw["max_arcsec"] - PAPER_TEXT_MAX_BEFORE_ARCSEC) < 0.05
                and abs(paper["max_arcsec"] - PAPER_TEXT_MAX_AFTER_ARCSEC) < 0.05
            ),
        },
        "model": {
            "phi_rad": model.phi_rad,
            "k": model.k,
            "scale_coefficient": model.scale_coefficient,
            "delta_l_mm": model.delta_l_mm,
            "torsion_arcsec_per_nm": slope,
            "sigma": sigma,
            "k_other_sign": other.k,
            "delta_l_other_sign_mm": other.delta_l_mm,
            "eccentricity_abs_mm": model.eccentricity_abs_mm,
            "dtau_min_rad": min(pt.dtau_rad for pt in geom.parts if pt.dtau_rad),
            "dtau_max_rad": max(pt.dtau_rad for pt in geom.parts),
            "literal_k": lit.k,
            "literal_eq16_bracket": lit.eq16_bracket,
        },
        "calibration": {key: res.to_dict() for key, res in fits.items()},
        "reference_u_arcsec": REFERENCE_U_ARCSEC,
    }


def _f(x: float, nd: int = 2) -> str:
    return f"{x:.{nd}f}"


def render_markdown(result: dict[str, Any]) -> str:
    """The documentation page (docs/table4.md), generated entirely from ``table4_comparison``."""
    rows = result["rows"]
    by = {r["key"]: r for r in rows}
    pc = result["paper_column"]
    cl = result["paper_text_claims"]
    m = result["model"]
    fit = result["calibration"]["offset_scale"]
    off = fit["terms"]["offset"]
    sc = fit["terms"]["scale"]
    scale_only = result["calibration"]["scale"]["terms"]["scale"]
    corr = fit["residual_correlation"]
    unc_sc = fit["uncertainty"]["scale.coefficient"]
    reading = fit["uncertainty"]["compensated_angle_arcsec"]
    ref_u = result["reference_u_arcsec"]

    def _u(term: dict[str, Any]) -> str:
        entry = fit["uncertainty"][f"{'offset' if term is off else 'scale'}.{term['parameter']}"]
        v, u = round_to_uncertainty(entry["value"], entry["U"])
        return f"{v} ± {u}"
    lines = [
        "# The paper's Table 4: what its compensation is, what the model predicts, what a calibration achieves",
        "",
        "<!-- Generated by `tcms table4 --markdown > docs/table4.md`; a test checks this page equals the command "
        "output. Do not edit by hand. -->",
        "",
        f"Data: {result['source']['table']} of the founding paper, {result['source']['n_points']} torque steps "
        "(0…1700 N·m), transcribed verbatim to `tcms_daq/compensation/data/paper_table4.csv` (provenance in "
        "`paper_table4.toml`). Geometry for the model prediction: `config/geometry-paper.toml` (Tables 2 and 3). "
        "Every error is (angle − autocollimator) in arcsec over all points; \"mean rel.\" is the mean of "
        "|error| / autocollimator angle over the points above 1″.",
        "",
        "Reproduce: `tcms table4` (human-readable) or `tcms table4 --json`. Held-out errors: 5 contiguous blocks "
        "is the headline (the points are a series with correlated errors); leave-one-out is shown beside it.",
        "",
        "| compensation | kind | RMS (″) | max (″) | mean (″) | mean rel. (%) |",
        "|---|---|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(
            f"| {r['label']} | {r['kind']} | {_f(r['rms_arcsec'])} | {_f(r['max_arcsec'])} | "
            f"{_f(r['mean_arcsec'])} | {_f(r['mean_relative_percent'])} |"
        )
    lines += [
        "",
        "## What the numbers say",
        "",
        f"- **The paper's compensated column is the encoder reading divided by 1.03.** A least-squares scale of "
        f"the column against the encoder gives {pc['ls_scale_vs_encoder']:.5f} (1/1.03 = {pc['one_over_1_03']:.5f}); "
        f"the point ratios lie in {pc['ratio_min']:.5f}…{pc['ratio_max']:.5f}, and the column differs from "
        f"encoder/1.03 by at most {_f(pc['max_abs_difference_from_encoder_over_1_03_arcsec'])}″. It is a pure "
        f"{(1 - pc['ls_scale_vs_encoder']) * 100:.1f} % scale, not a torque-dependent correction.",
        f"- **The paper's text does not match its own table.** The text says the maximum error fell from "
        f"{cl['max_before_arcsec']}″ to {cl['max_after_arcsec']}″ and the error from {cl['percent_before']} % to "
        f"{cl['percent_after']} %; Table 4 gives a maximum of {_f(cl['table_max_before_arcsec'])}″ → "
        f"{_f(cl['table_max_after_arcsec'])}″ (RMS {_f(cl['table_rms_before_arcsec'])}″ → "
        f"{_f(cl['table_rms_after_arcsec'])}″).",
        f"- **The geometric model does not predict the paper's factor from Tables 2–3.** With the printed "
        f"inputs the tilt is φ = {m['phi_rad']:.7f} rad; the consistent completion gives k = {m['k']:.4f} "
        f"(σ = {m['sigma']:+d}, encoder under-reads by {abs(m['k'] - 1) * 100:.1f} %) or k = {m['k_other_sign']:.4f} "
        f"(σ = {-m['sigma']:+d}), the printed Eqs. 15/16 taken literally give k = {m['literal_k']:.4f} — none is "
        f"near the measured over-reading (calibrated scale coefficient {scale_only['value'] * 100:.2f} %). The "
        f"Table-3 perpendicularity errors ({m['dtau_min_rad'] * 1000:.0f}–{m['dtau_max_rad'] * 1000:.0f} mrad) "
        f"tilt the shaft axis so far that its lever arm puts the measurement point "
        f"{m['eccentricity_abs_mm']:.1f} mm off the encoder axis, hence the large scale. The torsion term alone "
        f"(ΔL = {m['delta_l_mm']:.3f} mm, {m['torsion_arcsec_per_nm'] * 1000:.3f}″ per 1000 N·m) has the right "
        f"sign and removes part of the error (RMS {_f(by['model_torsion']['rms_arcsec'])}″).",
        f"- **A calibrated offset + scale is as good as the paper's compensation on held-out points — not "
        f"measurably better.** Fitted to the autocollimator: offset {_u(off)}″, scale coefficient {_u(sc)} "
        f"(expanded U for 95 %; θ_c = θ − offset − coefficient·θ). Held out in {fit['blocked_cv_blocks']} "
        f"contiguous blocks (the headline figure) its RMS is {_f(fit['blocked_cv_rms_arcsec'])}″ and its max "
        f"{_f(fit['blocked_cv_max_arcsec'])}″, against the paper's {_f(by['paper']['rms_arcsec'])}″ RMS and "
        f"{_f(by['paper']['max_arcsec'])}″ max. Leave-one-out "
        f"gives {_f(fit['loo_rms_arcsec'])}″, which is optimistic here: a left-out point's neighbours, with "
        f"nearly the same error, stay in the fit. With about {corr['n_eff']:.0f} independent points an RMS is "
        f"itself uncertain by about ±{100 / math.sqrt(2 * corr['n_eff']):.0f} % (1/√(2·n_eff)), more than the "
        f"difference. What remains is a slow wiggle this data set cannot attribute to the encoder (the "
        "autocollimator and the encoder were read in separate loading runs).",
        f"- **The uncertainty of the calibration.** The residuals in measurement order have lag-1 autocorrelation "
        f"{corr['lag1_autocorrelation']:.2f} (Durbin–Watson {corr['durbin_watson']:.2f}): neighbouring points share "
        f"their error, so the {corr['n']:.0f} points are worth n_eff = n(1 − ρ)/(1 + ρ) = {corr['n_eff']:.1f} "
        f"independent ones, with ρ = {corr['error_autocorrelation']:.2f} the AR(1) correlation of the errors that "
        f"gives the residuals of this fit their ρ₁ on average (a fit absorbs the slow part of its errors), plus half "
        f"its standard error. The coefficients' Type A covariance is that of AR(1) errors, σ²(XᵀX)⁻¹XᵀR(XᵀX)⁻¹ with "
        f"R_ij = ρ^|i−j|, with n_eff − 2 = {unc_sc['dof']:.1f} degrees of freedom "
        f"(k = {unc_sc['k']:.2f}; on synthetic AR(1) residuals this U covers the truth in 93–98 % of draws), and the "
        f"autocollimator's {ref_u:g}″ (a common offset of its readings) is a Type B input; treating the residuals as "
        f"independent would state U several times too small. One compensated reading "
        f"within the calibrated range (up to {reading['at_angle_arcsec']:.0f}″) is good to ±"
        f"{round_to_uncertainty(0.0, reading['U'])[1]}″ (U, k = {reading['k']:.2f}: the blocked held-out error and "
        "the reference).",
        "",
    ]
    return "\n".join(lines)


def format_table4(result: dict[str, Any]) -> str:
    lines = [f"{'compensation':<66} {'rms':>7} {'max':>7} {'mean':>7} {'rel%':>6}"]
    for r in result["rows"]:
        lines.append(
            f"{r['label']:<66} {r['rms_arcsec']:7.2f} {r['max_arcsec']:7.2f} {r['mean_arcsec']:7.2f} "
            f"{r['mean_relative_percent']:6.2f}"
        )
    pc = result["paper_column"]
    cl = result["paper_text_claims"]
    lines.append(
        f"paper column = encoder x {pc['ls_scale_vs_encoder']:.5f} (1/1.03 = {pc['one_over_1_03']:.5f}, "
        f"max deviation {pc['max_abs_difference_from_encoder_over_1_03_arcsec']:.2f}″)"
    )
    lines.append(
        f"paper text claims max {cl['max_before_arcsec']}″ -> {cl['max_after_arcsec']}″; its table gives "
        f"{cl['table_max_before_arcsec']:.2f}″ -> {cl['table_max_after_arcsec']:.2f}″"
    )
    return "\n".join(lines)

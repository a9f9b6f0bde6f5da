"""Every word the test certificate prints, in one catalogue per language (the template and the loop figure take
their text from here; nothing user-facing is written in ``certificate.typ`` or ``certificate.py``).

Keys are stable names; values may hold ``{name}`` fields filled by :func:`text`. A translation is another dict with
the same keys (``CATALOGUES``); a key it lacks falls back to English.
"""

from __future__ import annotations

from typing import Any

EN: dict[str, str] = {
    # title block
    "title": "Test certificate",
    "subtitle": "Torsional rigidity and lost motion of a precision reducer",
    "certificate_no": "Certificate no.",
    "issued_by": "Issued by",
    "footer": "Certificate {run_id} · issued {issued_at} UTC by TCMS-DAQ {software_version}",
    "page": "page",
    "not_completed": "Run {status}: {error}; this document records what was measured and certifies nothing.",
    "not_completed_error": "the test did not complete",
    # customer and item
    "section_item": "Customer and item tested",
    "customer": "Customer",
    "order_number": "Order number",
    "reducer": "Reducer (model)",
    "serial_number": "Serial number",
    "not_stated": "not stated",
    # the test
    "section_test": "Test",
    "method": "Test method",
    "method_single": "GB/T 35089-2018, torsional rigidity and lost motion from the hysteresis curve",
    "method_positions": "GB/T 40731-2021, at several output positions (the result is the worst of them)",
    "method_rates": "GB/T 35089-2018, repeated at each loading rate (the result is the worst of them)",
    "bench": "Test bench",
    "bench_id": "id {bench_id}",
    "started": "Test started",
    "ambient": "Ambient temperature",
    "ambient_value": "{value} °C ({source})",
    "ambient_source_request": "as stated for this test",
    "ambient_source_config": "test room, bench configuration",
    "ambient_not_recorded": "not recorded",
    "tested_by": "Tested by",
    "never_started": "never started",
    "utc": "UTC",
    # parameters
    "section_parameters": "Test parameters",
    "param_max_torque_nm": "Test torque",
    "param_cycles": "Evaluated loops",
    "param_profile": "Loading profile",
    "param_rate_nm_per_s": "Torque rate",
    "param_step_nm": "Torque step",
    "param_dwell_s": "Dwell per step",
    "param_conditioning_loops": "Conditioning loops",
    "param_tip_dwell_s": "Dwell at ±T",
    "param_start": "First load direction",
    "param_decision_rule": "Decision rule",
    "param_positions_deg": "Output positions",
    "param_move_velocity_deg_per_s": "Output speed between positions",
    "param_rates_nm_per_s": "Loading rates",
    "value_continuous": "continuous",
    "value_stepped": "stepped",
    "value_negative": "negative (−T first)",
    "value_positive": "positive (+T first)",
    "value_guarded": "guarded acceptance",
    "value_simple": "simple acceptance",
    # the loop
    "section_loop": "Hysteresis curve",
    "loop_caption": ("Twist angle relative to the loop's centre (the midline at zero torque) against torque, every "
                     "evaluated loop; the evaluation's lines drawn."),
    "loop_caption_stages": ("Twist angle of each {stage}, relative to its own loop centre (the midline at zero "
                            "torque), against torque: the evaluated loops of every {stage} overlaid."),
    "no_samples": "No samples were recorded.",
    "axis_torque": "torque / N·m",
    "axis_twist": "twist relative to the loop centre / arcmin",
    "legend_measured": "measured (compensated)",
    "legend_secant": "rigidity secant ({lo}–{hi} N·m)",
    "legend_lost_motion": "lost motion at ±{torque} N·m",
    "legend_backlash": "backlash at zero torque",
    "legend_interval": "rigidity interval",
    "legend_lost_motion_torque": "lost-motion torque ±{torque} N·m",
    "legend_position": "{value}°",
    "legend_rate": "{value} N·m/s",
    # results
    "section_results": "Results",
    "col_quantity": "Quantity",
    "col_result": "Result (value ± U)",
    "col_dominant": "Dominant contribution",
    "q_rigidity_nm_per_arcmin": "Torsional rigidity",
    "q_lost_motion_arcsec": "Lost motion",
    "q_backlash_arcsec": "Backlash",
    "q_positive_rigidity_nm_per_arcmin": "Torsional rigidity, positive torque",
    "q_negative_rigidity_nm_per_arcmin": "Torsional rigidity, negative torque",
    "q_k1_nm_per_rad": "Torsional rigidity K1 (Harmonic Drive, lowest region)",
    "q_k2_nm_per_rad": "Torsional rigidity K2 (Harmonic Drive, middle region)",
    "q_k3_nm_per_rad": "Torsional rigidity K3 (Harmonic Drive, highest region)",
    "q_loop_energy_j": "Hysteresis loss per loop",
    "summary_single": "The results are the mean over the evaluated loops.",
    "summary_stages": ("The results are the worst of the {n} {stages}: the lowest rigidity, the largest lost motion "
                       "and the largest backlash (each {stage}'s results in the table below)."),
    "u_note": ("U: expanded uncertainty for a coverage probability of about 95 % (coverage factor k as stated), "
               "rounded to two significant digits; each value is rounded to the decimal place of its U "
               "(JCGM 100). Basis of the evaluation: {basis}."),
    "basis_none": "no uncertainty evaluation recorded",
    "u_not_stated": "U not stated",
    # stages
    "section_positions": "Results at each output position",
    "section_rates": "Results at each loading rate",
    "stage_position": "position",
    "stage_positions": "output positions",
    "stage_rate": "loading rate",
    "stage_rates": "loading rates",
    "col_position": "Position / °",
    "col_rate": "Loading rate / N·m/s",
    "col_rigidity": "Rigidity / N·m/arcmin",
    "col_lost_motion": "Lost motion / arcsec",
    "col_backlash": "Backlash / arcsec",
    "row_worst": "Result: worst of {n}",
    "row_spread": "Spread (largest − smallest)",
    "row_per_decade": "Change per tenfold loading rate",
    # decision
    "section_decision": "Decision",
    "decision_rule": "Decision rule",
    "col_requirement": "Requirement",
    "col_measured": "Measured",
    "col_guard_band": "Guard band",
    "col_decision": "Decision",
    "guard_none": "none",
    "decision_pass": "pass",
    "decision_fail": "fail",
    "decision_undecided": "undecided",
    "decision_none": "none",
    "verdict": "Verdict",
    "warnings": "Warnings",
    "rule_guarded": ("guarded acceptance (ISO 14253-1): a result passes only when value ± U lies within its "
                     "limits, fails when value ± U lies outside them, and is undecided otherwise"),
    "rule_simple": "simple acceptance: the measured value against its limits (measurement uncertainty not applied)",
    "rule_unstated": ("simple acceptance: the measured value against its limits (no decision rule stated with the "
                      "results)"),
    # instruments
    "section_instruments": "Measuring instruments and traceability",
    "col_instrument": "Instrument",
    "col_device": "Device",
    "col_calibration": "Calibration",
    "kind_angle": "angle encoder",
    "kind_torque": "torque sensor",
    "kind_loader": "servo loader",
    "device_driver": "{device} ({driver})",
    "device_unnamed": "not named in the bench configuration ({driver})",
    "cal_certificate": "certificate {value}",
    "cal_laboratory": "by {value}",
    "cal_calibrated_on": "calibrated {value}",
    "cal_due": "due {value}",
    "cal_uncertainty": "U = {value}",
    "cal_not_stated": "not stated in the bench configuration",
    "no_config": "the run recorded no bench configuration",
    "traceability": "Traceability",
    "traceability_default": ("The measuring instruments listed are calibrated by the laboratories named, whose "
                             "certificates state the traceability of their results to the International System of "
                             "Units (SI) through national measurement standards; the evaluation of uncertainty "
                             "follows JCGM 100 (GUM)."),
    # compensation
    "section_compensation": "Encoder compensation and bench model",
    "compensation_version": "Compensation version",
    "compensation_sha": "SHA-256 of the compensator",
    "bench_model_version": "Bench model version",
    "not_recorded": "not recorded",
    "software": "Software",
    # approval
    "section_approval": "Approval",
    "approval_tested": "Tested by",
    "approval_approved": "Approved by",
    "approval_name": "Name",
    "approval_signature": "Signature",
    "approval_date": "Date",
}

#: the catalogues by language; issue 26 adds "zh" (Simplified Chinese) with the same keys
CATALOGUES: dict[str, dict[str, str]] = {"en": EN}


def catalogue(lang: str = "en") -> dict[str, str]:
    """The whole catalogue of ``lang`` (English for a key it lacks, and for an unknown language)."""
    return {**EN, **CATALOGUES.get(lang, {})}


def text(key: str, lang: str = "en", **fields: Any) -> str:
    """The catalogue's text for ``key`` with its ``{fields}`` filled."""
    template = CATALOGUES.get(lang, {}).get(key, EN[key])
    return template.format(**fields) if fields else template

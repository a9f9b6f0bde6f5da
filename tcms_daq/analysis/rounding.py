"""A result as "value ± U (k = …)": U rounded to two significant digits, the value to the same decimal place
(JCGM 100 7.2.6). The one rendering the table, the HTML report and the calibration output share (the dashboard
does the same in app.js). Units are shown as the results' ``unit`` names them ("arcsec" as ″).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

SIGNIFICANT_DIGITS = 2
NOT_STATED = "U not stated"


def round_to_uncertainty(value: float, expanded: float, digits: int = SIGNIFICANT_DIGITS) -> tuple[str, str]:
    """(value, U) as strings: U to ``digits`` significant digits, the value to the same decimal place."""
    if not (math.isfinite(expanded) and expanded > 0.0):
        return f"{value:.6g}", f"{expanded:g}"
    exponent = math.floor(math.log10(expanded)) - (digits - 1)
    rounded = round(expanded, -exponent)
    if rounded >= 10.0 ** (exponent + digits):  # 0.0996 → 0.10: one digit fewer after rounding up
        exponent += 1
        rounded = round(expanded, -exponent)
    decimals = max(0, -exponent)
    shown_value = round(value, -exponent)
    return f"{shown_value:.{decimals}f}", f"{rounded:.{decimals}f}"


def unit_suffix(unit: str) -> str:
    return "″" if unit == "arcsec" else f" {unit}" if unit else ""


def with_uncertainty(value: float | None, entry: Mapping[str, Any] | None, unit: str | None = None) -> str:
    """"293.9 ± 2.3 N·m/arcmin (k = 2.05)" from a result and its ``uncertainty`` entry; "value (U not stated)"
    without one; "—" without a value."""
    if value is None or not math.isfinite(value):
        return "—"
    unit = unit if unit is not None else str((entry or {}).get("unit", ""))
    expanded = (entry or {}).get("U")
    if not isinstance(expanded, int | float) or not math.isfinite(expanded):
        return f"{value:.6g}{unit_suffix(unit)} ({NOT_STATED})"
    v, u = round_to_uncertainty(float(value), float(expanded))
    k = (entry or {}).get("k")
    k_text = f" (k = {k:.2f})" if isinstance(k, int | float) else ""
    return f"{v} ± {u}{unit_suffix(unit)}{k_text}"

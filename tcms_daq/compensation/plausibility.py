"""Plausibility of a compensator before it is used on a bench (an uploaded file can be valid TOML and still
wreck every result: a scale coefficient of 0.5 turns 304 N·m/arcmin into 590)."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

from tcms_daq.compensation.compensator import Compensator


@dataclass(frozen=True)
class PlausibilityBounds:
    """max_scale: largest |scale coefficient| (a 10 % scale error of an encoder chain is already gross);
    min_period_arcsec: shortest period of a periodic term (below the encoder's resolution it is noise, and the
    compensator would alias it); max_correction_arcsec: largest angle parameter (offset, amplitude) of a term
    (a degree: more is a mounting fault to repair, not to compensate)."""

    max_scale: float = 0.10
    min_period_arcsec: float = 1.0
    max_correction_arcsec: float = 3600.0


def plausibility_problems(comp: Compensator, bounds: PlausibilityBounds = PlausibilityBounds()) -> list[str]:
    """One line per implausible term parameter (empty: plausible)."""
    problems: list[str] = []
    for term in comp.terms:
        label = term.label()
        for f in dataclasses.fields(term):  # every Term subclass is a dataclass
            value = getattr(term, f.name)
            if not isinstance(value, int | float) or isinstance(value, bool):
                continue
            if not math.isfinite(value):
                problems.append(f"{label}: {f.name} is {value}, not a finite number")
            elif (f.name.endswith("_arcsec") and f.name != "period_arcsec"
                  and abs(value) > bounds.max_correction_arcsec):
                problems.append(f"{label}: {f.name} {value:g}″ exceeds ±{bounds.max_correction_arcsec:g}″")
        coefficient = getattr(term, "coefficient", None)
        if label == "scale" and coefficient is not None and abs(coefficient) > bounds.max_scale:
            problems.append(f"scale: coefficient {coefficient:g} is outside ±{bounds.max_scale:g} "
                            f"(a {abs(coefficient):.0%} scale error)")
        period = term.angle_period_arcsec()
        if label.startswith("periodic") and period is not None and period < bounds.min_period_arcsec:
            problems.append(f"{label}: period {period:g}″ is below {bounds.min_period_arcsec:g}″")
    return problems

"""The discrepancy workflow on the transmission error: measured TE against the unit's model, the harmonics the model
lacks found, named by their order and component, added to the model; the next run's comparison is ``consistent``.

The unit's model is a list of harmonics (order per output revolution, amplitude, phase, component) in a TOML file of
its own, like the stiffness bench's model (``tcms_daq.discrepancy.model_file``)::

    format = "tcms-te-model/1"
    reducer = "RV-110E"
    ratio = 161.0
    version = 2
    [[harmonics]]
    order = 39.0
    amplitude_arcsec = 3.0
    phase_deg = 110.0                # TE = A·sin(order·φ + phase), φ the output angle (the output encoder's)
    component = "pin_ring"           # absent: an order that belongs to no component (added on request only)
    source = "te discrepancy of run 12"
    [harmonics.standard_uncertainty] # k = 1, from the run that found it
    amplitude_arcsec = 0.01
    phase_deg = 0.2

:func:`compare_te`, per direction of rotation: r(φ) = TE − model(φ) on the even grid of the output angle
(``te.te_records``), the lines of r found by the same pursuit as the evaluation (``te.find_lines``: a line must
stand out of the local noise so that noise alone makes one in 1 % of spectra), the lines of both directions at one
order combined. Each finding names the components at its order (within half a bin, ``kinematics.components_at``)
or none; one at an order the model already has is a correction of that harmonic.

A finding no larger than what the measuring chain alone can make at its order (``allowance``: the encoders' errors
and the readings' skew, as the budgets count them) is reported but is not a gap of the model. The verdict:

* ``consistent`` — nothing in r stands out of the noise and the measuring chain;
* ``explained`` — every finding names a component (applying them closes the gap);
* ``partially_explained`` — some findings name a component, some belong to no component;
* ``unexplained`` — no finding names a component: each is reported by its order, never given a name.

:func:`apply_findings` adds the named findings to the model (a correction adds to the harmonic it corrects: r is
what the model lacks on top of it) and raises its version; unexplained orders are added only when asked, without a
component.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Literal

import numpy as np
import numpy.typing as npt
import tomli_w
from threadpoolctl import threadpool_limits

from tcms_daq.errors import DataFormatError
from tcms_daq.tomlfile import load_formatted_toml
from tcms_daq.transmission.kinematics import Teeth, order_table
from tcms_daq.transmission.te import (
    DIRECTIONS,
    FALSE_ALARM,
    TeDirection,
    TeLine,
    TeRecord,
    combine_directions,
    evaluate_direction,
    te_records,
)

FORMAT = "tcms-te-model/1"
Verdict = Literal["consistent", "explained", "partially_explained", "unexplained"]


@dataclass(frozen=True)
class TeHarmonicTerm:
    """One harmonic of a unit's TE model: TE += A·sin(order·φ + phase) (φ in rad, phase in deg)."""

    order_per_output_rev: float
    amplitude_arcsec: float
    phase_deg: float
    component: str | None = None
    source: str = ""
    standard_uncertainty: dict[str, float] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"order": float(self.order_per_output_rev),
                               "amplitude_arcsec": float(self.amplitude_arcsec), "phase_deg": float(self.phase_deg)}
        if self.component is not None:
            out["component"] = self.component
        if self.source:
            out["source"] = self.source
        if self.standard_uncertainty:
            out["standard_uncertainty"] = {k: float(v) for k, v in self.standard_uncertainty.items()}
        return out


@dataclass(frozen=True)
class TeModel:
    """A unit's TE model (module docstring): its harmonics, the ratio they refer to, a version raised by every
    apply."""

    ratio: float
    harmonics: tuple[TeHarmonicTerm, ...] = ()
    reducer: str | None = None
    version: int = 1

    def predict_arcsec(self, output_angle_rad: npt.ArrayLike) -> np.ndarray:
        """The model's TE (″) at output angles (rad)."""
        phi = np.asarray(output_angle_rad, dtype=float)
        out = np.zeros_like(phi)
        for h in self.harmonics:
            out += h.amplitude_arcsec * np.sin(h.order_per_output_rev * phi + math.radians(h.phase_deg))
        return out

    def to_toml(self) -> str:
        doc: dict[str, Any] = {"format": FORMAT, "ratio": float(self.ratio), "version": int(self.version)}
        if self.reducer is not None:
            doc["reducer"] = self.reducer
        doc["harmonics"] = [h.to_dict() for h in self.harmonics]
        head = "# TCMS-DAQ transmission-error model of one unit: TE = sum A sin(order phi + phase), docs/transmission.md\n"
        return head + tomli_w.dumps(doc)

    def save(self, path: str | Path) -> None:
        Path(path).write_text(self.to_toml(), encoding="utf-8")


def parse_te_model(text: str, source: str = "<te model>") -> TeModel:
    """Parse a TE model file; DataFormatError with one line naming the problem."""
    doc = load_formatted_toml(text, source, FORMAT)
    ratio = doc.get("ratio")
    if not isinstance(ratio, int | float) or not ratio > 0:
        raise DataFormatError(f"{source}: ratio must be a number > 0")
    terms = []
    for i, h in enumerate(doc.get("harmonics", [])):
        try:
            order, amp, phase = float(h["order"]), float(h["amplitude_arcsec"]), float(h.get("phase_deg", 0.0))
        except (KeyError, TypeError, ValueError):
            raise DataFormatError(f"{source}: harmonics[{i}]: needs numbers order and amplitude_arcsec") from None
        if not (order > 0 and amp >= 0 and math.isfinite(order) and math.isfinite(amp) and math.isfinite(phase)):
            raise DataFormatError(f"{source}: harmonics[{i}]: order must be > 0, amplitude_arcsec >= 0")
        terms.append(TeHarmonicTerm(order, amp, phase, h.get("component"), str(h.get("source", "")),
                                    {k: float(v) for k, v in h.get("standard_uncertainty", {}).items()}))
    return TeModel(float(ratio), tuple(terms), doc.get("reducer"), int(doc.get("version", 1)))


def load_te_model(path: str | Path) -> TeModel:
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise DataFormatError(f"{path}: cannot read ({exc})") from None
    return parse_te_model(text, str(path))


# ------------------------------------------------------------------------------------------------- comparison


@dataclass(frozen=True)
class TeFinding:
    """A line of the residual TE − model: what the model lacks at ``order`` (amplitude, phase in the model's
    convention, their standard uncertainties), the components at that order (empty: none), whether it corrects a
    harmonic the model has, the directions it was found in, and what the measuring chain alone can make at that
    order (``allowance_arcsec``, expanded, k = 2): a finding within it is not a gap of the model."""

    line: TeLine
    corrects: float | None  # the order of the model's harmonic it corrects, or None: a missing harmonic
    allowance_arcsec: float = 0.0

    @property
    def named(self) -> bool:
        return bool(self.line.components)

    @property
    def significant(self) -> bool:
        """Larger than what the measuring chain can make at its order."""
        return self.line.amplitude_arcsec > self.allowance_arcsec

    def to_dict(self) -> dict[str, Any]:
        return {**self.line.to_dict(), "corrects_order": self.corrects,
                "kind": "correction" if self.corrects is not None else "missing",
                "named": self.named, "allowance_arcsec": self.allowance_arcsec, "significant": self.significant}

    def describe(self) -> str:
        ln = self.line
        what = (f"{ln.component}" if self.named else "no component of the kinematics")
        change = "its model harmonic is off by" if self.corrects is not None else "missing from the model:"
        return (f"order {ln.order_per_output_rev:.4g} per output revolution ({what}): {change} "
                f"{ln.amplitude_arcsec:.3g}″ at {ln.phase_deg:.1f}°")


@dataclass
class TeComparison:
    """The outcome of :func:`compare_te` (``to_dict()`` is the JSON form)."""

    verdict: Verdict
    findings: list[TeFinding]
    per_direction: dict[str, TeDirection]
    rms_residual_arcsec: float
    noise_amplitude_arcsec: float
    model_version: int

    @property
    def gaps(self) -> list[TeFinding]:
        """The findings beyond what the measuring chain can make: the model's gaps."""
        return [f for f in self.findings if f.significant]

    @property
    def named(self) -> list[TeFinding]:
        return [f for f in self.gaps if f.named]

    @property
    def unexplained(self) -> list[TeFinding]:
        return [f for f in self.gaps if not f.named]

    @property
    def words(self) -> str:
        within = len(self.findings) - len(self.gaps)
        note = (f" ({within} line{'s' if within != 1 else ''} within what the measuring chain can make)"
                if within else "")
        if self.verdict == "consistent":
            return (f"the measured transmission error agrees with the model (version {self.model_version}): nothing "
                    f"beyond the noise ({self.noise_amplitude_arcsec:.2g}″ per line) and the measuring chain{note}")
        return f"{self.verdict.replace('_', ' ')}: " + "; ".join(f.describe() for f in self.gaps) + note

    def to_dict(self) -> dict[str, Any]:
        return {"verdict": self.verdict, "verdict_words": self.words,
                "findings": [f.to_dict() for f in self.findings],
                "unexplained_orders": [f.line.order_per_output_rev for f in self.unexplained],
                "named_orders": [f.line.order_per_output_rev for f in self.named],
                "rms_residual_arcsec": self.rms_residual_arcsec, "noise_amplitude_arcsec": self.noise_amplitude_arcsec,
                "model_version": self.model_version,
                "per_direction": {k: v.to_dict() for k, v in self.per_direction.items()}}


def _residual(record: TeRecord, model: TeModel) -> TeRecord:
    return replace(record, te_arcsec=record.te_arcsec - model.predict_arcsec(record.phi_rad))


Allowance = Callable[[list[float]], list[float]]


def compare_te(time_s: npt.ArrayLike, input_angle_arcsec: npt.ArrayLike, output_angle_arcsec: npt.ArrayLike,
               model: TeModel, *, teeth: Teeth | None = None, max_order_per_output_rev: float | None = None,
               false_alarm: float = FALSE_ALARM, allowance: Allowance | None = None) -> TeComparison:
    """Compare a transmission-error record (both directions) with the unit's model (module docstring); ``teeth``
    names the orders (None: every finding is reported by its order alone); ``allowance``: the amplitude (″,
    expanded) the measuring chain alone can make at each of a list of orders
    (``tcms_daq.uncertainty.station.te_allowance``; None: none, every line of the residual counts)."""
    records = te_records(time_s, input_angle_arcsec, output_angle_arcsec, ratio=model.ratio)
    table = order_table(teeth) if teeth is not None else None
    with threadpool_limits(limits=1, user_api="blas"):  # many small least-squares fits: threads cost more
        per_direction = {name: evaluate_direction(_residual(records[name], model), table, max_order_per_output_rev,
                                                  false_alarm, None, True) for name in DIRECTIONS}
    tolerance = 0.5 / min(d.revolutions for d in per_direction.values())
    lines = combine_directions(per_direction)
    allowed = allowance([ln.order_per_output_rev for ln in lines]) if allowance is not None and lines else \
        [0.0] * len(lines)
    findings = []
    for line, allow in zip(lines, allowed, strict=True):
        near = [h.order_per_output_rev for h in model.harmonics
                if abs(h.order_per_output_rev - line.order_per_output_rev) <= tolerance]
        findings.append(TeFinding(line, near[0] if near else None, float(allow)))
    gaps = [f for f in findings if f.significant]
    named = [f for f in gaps if f.named]
    if not gaps:
        verdict: Verdict = "consistent"
    elif len(named) == len(gaps):
        verdict = "explained"
    elif named:
        verdict = "partially_explained"
    else:
        verdict = "unexplained"
    residuals = np.concatenate([_residual(r, model).te_arcsec - np.mean(_residual(r, model).te_arcsec)
                                for r in records.values()])
    noise = float(np.mean([d.noise_amplitude_arcsec for d in per_direction.values()]))
    return TeComparison(verdict, findings, per_direction, float(np.sqrt(np.mean(residuals**2))), noise,
                        model.version)


def apply_findings(model: TeModel, comparison: TeComparison, *, source: str = "te discrepancy",
                   include_unexplained: bool = False) -> TeModel:
    """The model with the comparison's named findings added (a correction added to the harmonic it corrects, as
    vectors), and the unexplained ones too when ``include_unexplained`` (without a component); version + 1."""
    harmonics = list(model.harmonics)
    for f in comparison.gaps:
        if not f.named and not include_unexplained:
            continue
        ln = f.line
        unc = {"amplitude_arcsec": ln.u_amplitude_arcsec, "phase_deg": ln.u_phase_deg, "order": ln.u_order}
        if f.corrects is not None:
            idx = next(i for i, h in enumerate(harmonics) if h.order_per_output_rev == f.corrects)
            old = harmonics[idx]
            z = (old.amplitude_arcsec * complex(math.cos(math.radians(old.phase_deg)), math.sin(math.radians(old.phase_deg)))
                 + ln.amplitude_arcsec * complex(math.cos(math.radians(ln.phase_deg)), math.sin(math.radians(ln.phase_deg))))
            harmonics[idx] = replace(old, amplitude_arcsec=abs(z), phase_deg=math.degrees(math.atan2(z.imag, z.real)) % 360,
                                     source=f"{old.source}; corrected by {source}".lstrip("; "),
                                     standard_uncertainty=unc)
        else:
            harmonics.append(TeHarmonicTerm(ln.order_per_output_rev, ln.amplitude_arcsec, ln.phase_deg,
                                            ln.component, source, unc))
    return replace(model, harmonics=tuple(harmonics), version=model.version + 1)


def model_from_lines(lines: list[TeLine], ratio: float, *, reducer: str | None = None, source: str = "",
                     named_only: bool = True) -> TeModel:
    """A TE model from an evaluation's ``te_orders`` (its named lines, or all of them)."""
    terms = tuple(TeHarmonicTerm(ln.order_per_output_rev, ln.amplitude_arcsec, ln.phase_deg, ln.component, source,
                                 {"amplitude_arcsec": ln.u_amplitude_arcsec, "phase_deg": ln.u_phase_deg})
                  for ln in lines if ln.components or not named_only)
    return TeModel(float(ratio), terms, reducer)


__all__ = ["FORMAT", "TeComparison", "TeFinding", "TeHarmonicTerm", "TeModel", "apply_findings", "compare_te",
           "load_te_model", "model_from_lines", "parse_te_model"]

"""The discrepancy model file (TOML): the terms the workflow added to the simulated angle.

Format ``tcms-discrepancy-model/1``::

    format = "tcms-discrepancy-model/1"
    signal_period_arcsec = 72.0
    offset_arcsec = -0.41            # constant offset (always fitted, not an effect)
    drift_reference_time_s = 12.5    # t0 of a thermal drift r·(t − t0): the first fitted sample's time
    [fit_range]                      # the data the terms were fitted on (outside it they are extrapolations)
    time_s = [12.5, 85.2]
    torque_nm = [-800.4, 800.1]
    angle_arcsec = [-175.0, 171.2]

    [[terms]]                        # in order of addition
    name = "time_skew"               # a catalogue name (tcms_daq.discrepancy.catalogue)
    aliased_with = []                # other catalogue effects that fit these data equally well
    uncertainty_dof = 7              # degrees of freedom of u: the jackknife's groups g − 1 (absent: not estimated)
    coverage_factor = 2.365          # k of U: Student's t for uncertainty_dof, about 95 % (written for the reader)
    [terms.parameters]
    skew_s = 0.0201
    [terms.standard_uncertainty]     # k = 1, delete-one-loop jackknife (absent: not estimated)
    skew_s = 0.0003
    [terms.expanded_uncertainty]     # U = k·u (written for the reader; derived from u and uncertainty_dof)
    skew_s = 0.0007

The re-simulated angle is θ_sim + offset + Σ signature(term). The compensator's term registry
(``tcms_daq.compensation.terms``) models encoder errors as functions of (θ, T, t) only; ``time_skew``,
``backlash`` and ``torque_zero_offset`` need the trace (time shift, load direction, simulated curve), so the
discrepancy model has this file of its own. The same ``[[terms]]`` map one-to-one onto the simulated bench's
``[sim.effects]`` table (:func:`sim_effects_table`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import tomli_w

from tcms_daq.discrepancy import catalogue as cat
from tcms_daq.discrepancy.design import build_design
from tcms_daq.discrepancy.workflow import coverage_factor
from tcms_daq.errors import DataFormatError
from tcms_daq.samples import Samples
from tcms_daq.tomlfile import load_formatted_toml

FORMAT = "tcms-discrepancy-model/1"


@dataclass
class ModelTerm:
    name: str
    parameters: dict[str, float]
    aliased_with: list[str] = field(default_factory=list)
    standard_uncertainty: dict[str, float] = field(default_factory=dict)
    uncertainty_dof: int | None = None  # of standard_uncertainty: the jackknife's groups g − 1

    @property
    def coverage_factor(self) -> float | None:
        return coverage_factor(self.uncertainty_dof) if self.standard_uncertainty else None

    @property
    def expanded_uncertainty(self) -> dict[str, float]:
        """U = k·u (about 95 %) of every parameter with a u; empty without u or degrees of freedom."""
        k = self.coverage_factor
        return {key: k * u for key, u in self.standard_uncertainty.items()} if k is not None else {}

    def to_dict(self) -> dict[str, Any]:
        """The term as the file and the service's ``GET /api/model`` give it."""
        out: dict[str, Any] = {"name": self.name, "aliased_with": list(self.aliased_with),
                               "parameters": {k: float(v) for k, v in self.parameters.items()}}
        if self.standard_uncertainty:
            out["standard_uncertainty"] = {k: float(v) for k, v in self.standard_uncertainty.items()}
        if self.expanded_uncertainty:
            out["uncertainty_dof"] = int(self.uncertainty_dof or 0)
            out["coverage_factor"] = round(float(self.coverage_factor or 0.0), 3)
            out["expanded_uncertainty"] = self.expanded_uncertainty
        return out


@dataclass
class DiscrepancyModel:
    offset_arcsec: float = 0.0
    signal_period_arcsec: float = 72.0
    terms: list[ModelTerm] = field(default_factory=list)
    fit_range: dict[str, list[float]] = field(default_factory=dict)
    drift_reference_time_s: float | None = None

    def to_toml(self) -> str:
        doc: dict[str, Any] = {
            "format": FORMAT,
            "signal_period_arcsec": float(self.signal_period_arcsec),
            "offset_arcsec": float(self.offset_arcsec),
        }
        if self.drift_reference_time_s is not None:
            doc["drift_reference_time_s"] = float(self.drift_reference_time_s)
        if self.fit_range:
            doc["fit_range"] = {k: [float(x) for x in v] for k, v in self.fit_range.items()}
        doc["terms"] = [t.to_dict() for t in self.terms]
        head = "# TCMS-DAQ discrepancy model: terms added to the simulated angle (arcsec), see docs/discrepancy.md\n"
        return head + tomli_w.dumps(doc)

    def save(self, path: str | Path) -> None:
        Path(path).write_text(self.to_toml(), encoding="utf-8")

    def with_terms_of(self, other: DiscrepancyModel) -> DiscrepancyModel:
        """This model with ``other``'s terms after its own. Signatures add, so a term found against this model
        is exactly what it misses; the offset is not an effect and stays this model's (the fit range and drift
        reference are the latest analysis's)."""
        return DiscrepancyModel(self.offset_arcsec, self.signal_period_arcsec, [*self.terms, *other.terms],
                                dict(other.fit_range or self.fit_range),
                                other.drift_reference_time_s if other.drift_reference_time_s is not None
                                else self.drift_reference_time_s)


def model_from_result(result) -> DiscrepancyModel:
    """The model of a :class:`~tcms_daq.discrepancy.workflow.DiscrepancyResult` (accepted terms incl. alias
    representatives)."""
    alias_of = {a.representative: [n for n in a.names if n != a.representative] for a in result.aliases
                if a.in_model}
    terms = [ModelTerm(name, dict(params), alias_of.get(name, []), dict(result.uncertainties.get(name, {})),
                       result.uncertainty_dof if name in result.uncertainties else None)
             for name, params in result.model_terms]
    fit_range = {k: list(v) for k, v in result.fit_range.items() if v is not None}
    return DiscrepancyModel(result.offset_arcsec, result.signal_period_arcsec, terms, fit_range,
                            result.drift_reference_time_s)


def parse_model(text: str, source: str = "<model>") -> DiscrepancyModel:
    """Parse a model file; raises DataFormatError with a one-line message."""
    doc = load_formatted_toml(text, source, FORMAT)
    terms = []
    for i, t in enumerate(doc.get("terms", [])):
        name = t.get("name")
        if name not in cat.CATALOGUE:
            raise DataFormatError(f"{source}: terms[{i}]: unknown effect {name!r}")
        params = t.get("parameters", {})
        missing = [p for p in cat.CATALOGUE[name].parameters if p not in params]
        if missing:
            raise DataFormatError(f"{source}: terms[{i}] ({name}): missing parameter {missing[0]!r}")
        terms.append(ModelTerm(name, {k: float(v) for k, v in params.items()}, list(t.get("aliased_with", [])),
                               {k: float(v) for k, v in t.get("standard_uncertainty", {}).items()},
                               None if t.get("uncertainty_dof") is None else int(t["uncertainty_dof"])))
    fit_range = {k: [float(x) for x in v] for k, v in doc.get("fit_range", {}).items()}
    t0 = doc.get("drift_reference_time_s")
    return DiscrepancyModel(float(doc.get("offset_arcsec", 0.0)), float(doc.get("signal_period_arcsec", 72.0)), terms,
                            fit_range, None if t0 is None else float(t0))


def load_model(path: str | Path) -> DiscrepancyModel:
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise DataFormatError(f"{path}: cannot read ({exc})") from None
    return parse_model(text, str(path))


def apply_model(model: DiscrepancyModel, simulated: Samples, *, has_time: bool = True) -> Samples:
    """Re-simulate: the simulated angle with the model's offset and terms added (same rows and columns)."""
    data = build_design(simulated, simulated, signal_period_arcsec=model.signal_period_arcsec, has_time=has_time)
    angle = simulated.angle_arcsec + model.offset_arcsec
    for term in model.terms:
        angle = angle + cat.signature(term.name, data, term.parameters)
    return Samples(simulated.time_s, simulated.torque_nm, angle, dict(simulated.extra))


def sim_effects_table(model: DiscrepancyModel) -> dict[str, dict[str, float]]:
    """The model's terms as a simulated-bench ``[sim.effects]`` table (``sim.effects`` reads it)."""
    return {t.name: dict(t.parameters) for t in model.terms}


def resimulated_samples(result, simulated: Samples, measured: Samples) -> Samples:
    """The re-simulated run for CSV output: canonical columns plus the inputs and residuals before/after."""
    extra = {k: v for k, v in simulated.extra.items() if k == "run_id"}
    extra.update({
        "simulated_arcsec": simulated.angle_arcsec,
        "measured_arcsec": measured.angle_arcsec,
        "residual_before_arcsec": result.residual_before_arcsec,
        "residual_after_arcsec": result.residual_after_arcsec,
        "load_direction": np.asarray(result.data.direction, dtype=float),
    })
    return Samples(simulated.time_s, simulated.torque_nm, result.resimulated_angle_arcsec, extra)

"""Plausibility of a compensator before it is used on a bench (an uploaded file can be valid TOML and still
wreck every result: a scale coefficient of 0.5 turns 304 N·m/arcmin into 590).

Three checks, pure functions over the parsed TOML, the built compensator and a reference record:

* ``schema_problems``: a closed schema. A compensator file has ``[compensator]`` (its header keys) and
  ``[[terms]]`` only; a geometry file ``[structure]``, ``[parts.N]`` and ``[model]`` only. An unknown table or key
  (``[[compensator.terms]]``, a typo) is named, never dropped. The term count is bounded here, before anything
  is built from the terms.
* ``plausibility_problems``: each term's parameters within the bands of its type (:class:`CompensationChecks`).
* ``rigidity_change``: the relative change of the rigidity a reference record (raw encoder readings and torque)
  shows when compensated by the candidate instead of the compensator in use.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from tcms_daq.compensation.compensator import Compensator
from tcms_daq.compensation.terms import TERM_TYPES
from tcms_daq.config.models import CompensationChecks
from tcms_daq.errors import TcmsError
from tcms_daq.units import ARCSEC_PER_REV

__all__ = ["CompensationChecks", "ReferenceLoop", "plausibility_problems", "rigidity_change", "schema_problems",
           "synthetic_reference"]

COMPENSATOR_TABLES = frozenset({"compensator", "terms"})
GEOMETRY_TABLES = frozenset({"structure", "parts", "model"})
# the header keys a compensator file can carry (what Compensator.to_dict writes from its meta, and the calibration's)
COMPENSATOR_HEAD_KEYS = frozenset({"description", "source", "k", "delta_l_mm", "phi_rad", "n_points",
                                   "tolerance_arcsec"})
MIN_REFERENCE_SAMPLES = 20
MAX_REFERENCE_SAMPLES = 20_000  # a long run is thinned to this many samples for the rigidity comparison


def _unknown(keys: Any, allowed: frozenset[str], where: str) -> str | None:
    extra = sorted(str(k) for k in keys if k not in allowed)
    if not extra:
        return None
    return f"{where}: unknown {'key' if len(extra) == 1 else 'keys'} {', '.join(map(repr, extra))} " \
           f"(allowed: {', '.join(sorted(allowed))})"


def schema_problems(data: Mapping[str, Any], checks: CompensationChecks = CompensationChecks()) -> list[str]:
    """One line per violation of the closed schema of a compensator (or geometry) file's parsed TOML (empty:
    the layout is right; the values are checked when the compensator is built and by ``plausibility_problems``)."""
    if "structure" in data:  # a geometry file: its tables check their own keys when it is read
        problem = _unknown(data, GEOMETRY_TABLES, "geometry file")
        return [problem] if problem else []
    problems: list[str] = []
    problem = _unknown(data, COMPENSATOR_TABLES, "compensator file: top level")
    if problem:
        problems.append(problem)
    head = data.get("compensator", {})
    if isinstance(head, Mapping):
        problem = _unknown(head, COMPENSATOR_HEAD_KEYS, "[compensator]")
        if problem:
            problems.append(problem)
    else:
        problems.append("[compensator] must be a table")
    terms = data.get("terms", [])
    if not isinstance(terms, list):
        problems.append("terms must be an array of tables ([[terms]])")
        return problems
    if len(terms) > checks.max_terms:
        problems.append(f"{len(terms)} terms: more than the {checks.max_terms} a compensator may have")
        return problems  # not worth naming each of 10 000 terms
    for i, term in enumerate(terms):
        if not isinstance(term, Mapping):
            problems.append(f"terms[{i}] must be a table")
            continue
        cls = TERM_TYPES.get(term.get("type"))  # type: ignore[arg-type]
        if cls is None:
            problems.append(f"terms[{i}]: unknown term type {term.get('type')!r} "
                            f"(known: {', '.join(sorted(TERM_TYPES))})")
            continue
        fields = frozenset(f.name for f in dataclasses.fields(cls))
        problem = _unknown(term, fields | {"type", "uncertainty"}, f"terms[{i}] ({cls.type_name})")
        if problem:
            problems.append(problem)
        unc = term.get("uncertainty")
        if unc is not None:
            if not isinstance(unc, Mapping):
                problems.append(f"terms[{i}].uncertainty must be a table")
            elif problem := _unknown(unc, fields, f"terms[{i}].uncertainty"):
                problems.append(problem)
    return problems


def plausibility_problems(comp: Compensator, checks: CompensationChecks = CompensationChecks()) -> list[str]:
    """One line per implausible term parameter (empty: plausible); the bands are ``checks``'s."""
    problems: list[str] = []
    if len(comp.terms) > checks.max_terms:
        problems.append(f"{len(comp.terms)} terms: more than the {checks.max_terms} a compensator may have")
    for term in comp.terms:
        label = term.label()
        for f in dataclasses.fields(term):  # every Term subclass is a dataclass
            value = getattr(term, f.name)
            if not isinstance(value, int | float) or isinstance(value, bool):
                continue
            if not math.isfinite(value):
                problems.append(f"{label}: {f.name} is {value}, not a finite number")
            elif (f.name.endswith("_arcsec") and f.name != "period_arcsec"
                  and abs(value) > checks.max_offset_arcsec):
                problems.append(f"{label}: {f.name} {value:g}″ exceeds ±{checks.max_offset_arcsec:g}″")
        if term.type_name == "scale":
            coefficient = float(getattr(term, "coefficient", 0.0))
            if abs(coefficient) > checks.max_scale:
                problems.append(f"scale: coefficient {coefficient:g} is outside ±{checks.max_scale:g} "
                                f"(a {abs(coefficient):.0%} scale error)")
        elif term.type_name == "torsion":
            per_nm = float(getattr(term, "arcsec_per_nm", 0.0))
            if abs(per_nm) > checks.max_torsion_arcsec_per_nm:
                problems.append(f"torsion: arcsec_per_nm {per_nm:g} ″/N·m is outside "
                                f"±{checks.max_torsion_arcsec_per_nm:g} ″/N·m")
        elif term.type_name == "periodic":
            amplitude = math.hypot(float(getattr(term, "sin_arcsec", 0.0)), float(getattr(term, "cos_arcsec", 0.0)))
            if amplitude > checks.max_periodic_amplitude_arcsec:
                problems.append(f"{label}: amplitude {amplitude:g}″ exceeds {checks.max_periodic_amplitude_arcsec:g}″")
        period = term.angle_period_arcsec()
        if term.type_name == "periodic" and period is not None and not (
                checks.min_period_arcsec <= period <= ARCSEC_PER_REV):
            problems.append(f"{label}: period {period:g}″ is outside {checks.min_period_arcsec:g}″ … one "
                            f"revolution ({ARCSEC_PER_REV:g}″)")
    return problems


@dataclass(frozen=True)
class ReferenceLoop:
    """A record to judge a compensation change on: raw encoder readings (arcsec), torque (N·m), time (s), and
    what it is (``"run <id>"`` or ``"synthetic …"``)."""

    encoder_arcsec: np.ndarray
    torque_nm: np.ndarray
    time_s: np.ndarray
    source: str

    @classmethod
    def from_columns(cls, columns: Mapping[str, np.ndarray], source: str) -> ReferenceLoop | None:
        """The reference in a stored run's columns (thinned to ``MAX_REFERENCE_SAMPLES``), or None when it has
        no raw encoder channel or too few finite samples under torque."""
        names = ("encoder_arcsec", "torque_nm", "time_s")
        if any(name not in columns for name in names):
            return None
        enc, torque, time = (np.asarray(columns[name], dtype=float) for name in names)
        keep = np.isfinite(enc) & np.isfinite(torque) & np.isfinite(time)
        enc, torque, time = enc[keep], torque[keep], time[keep]
        step = max(1, len(enc) // MAX_REFERENCE_SAMPLES)
        loop = cls(enc[::step], torque[::step], time[::step], source)
        return loop if _loaded(loop.torque_nm).sum() >= MIN_REFERENCE_SAMPLES else None


def synthetic_reference(current: Compensator, max_torque_nm: float, rigidity_nm_per_arcmin: float,
                        n: int = 2001) -> ReferenceLoop:
    """A linear loop 0 → +T → −T → 0 of ``rigidity_nm_per_arcmin`` around output angle 0, read through the
    measuring chain that ``current`` compensates (so that ``current`` recovers the true twist)."""
    phase = np.linspace(0.0, 1.0, n)
    torque = max_torque_nm * np.interp(phase, [0.0, 0.25, 0.75, 1.0], [0.0, 1.0, -1.0, 0.0])
    twist_arcsec = torque / rigidity_nm_per_arcmin * 60.0
    time = phase * 60.0
    try:
        raw = current.encoder_reading(twist_arcsec, torque, time)
    except TcmsError:  # a chain that cannot be inverted: the raw readings are the twist itself
        raw = twist_arcsec
    return ReferenceLoop(np.asarray(raw, dtype=float), torque, time,
                         f"synthetic loop ±{max_torque_nm:g} N·m at {rigidity_nm_per_arcmin:g} N·m/arcmin")


def _loaded(torque_nm: np.ndarray) -> np.ndarray:
    """The samples the rigidity is judged on: |T| between 10 % and 100 % of the largest |T|."""
    peak = float(np.max(np.abs(torque_nm), initial=0.0))
    return (np.abs(torque_nm) >= 0.1 * peak) & (peak > 0)


def _compliance_arcsec_per_nm(comp: Compensator, ref: ReferenceLoop) -> float:
    """Least-squares slope dθ_c/dT (″/N·m) of the compensated reference over its loaded samples."""
    mask = _loaded(ref.torque_nm)
    angle = comp.apply(ref.encoder_arcsec[mask], ref.torque_nm[mask], ref.time_s[mask], exact=True)
    torque = ref.torque_nm[mask]
    ok = np.isfinite(angle)
    if ok.sum() < MIN_REFERENCE_SAMPLES or np.ptp(torque[ok]) == 0:
        return math.nan
    slope, _ = np.polyfit(torque[ok], angle[ok], 1)
    return float(slope)


def rigidity_change(current: Compensator, candidate: Compensator, reference: ReferenceLoop) -> float:
    """Relative change of the reference's rigidity (dT/dθ_c, least squares over |T| ≥ 10 % of its peak) when
    compensated by ``candidate`` instead of ``current``: +0.12 is 12 % stiffer. NaN when either compensation
    leaves no usable slope (a candidate that makes the loop flat or non-finite: treat as implausible)."""
    before = _compliance_arcsec_per_nm(current, reference)
    after = _compliance_arcsec_per_nm(candidate, reference)
    if not (math.isfinite(before) and math.isfinite(after)) or before <= 0 or after <= 0:
        return math.nan
    return before / after - 1.0


@dataclass(frozen=True)
class UploadJudgement:
    """What an upload would do. problems: schema and band violations (one line each; empty: the file is right);
    candidate: the compensator built from it (None when it could not be built); rigidity_change: relative change
    of the reference's rigidity (None when not judged, NaN when the candidate leaves no usable slope);
    reference: which record it was judged on; refused: the one-line reason the change is refused ("" if not)."""

    problems: list[str]
    candidate: Compensator | None = None
    rigidity_change: float | None = None
    reference: str = ""
    refused: str = ""

    def reason(self) -> str:
        """The first problem (and how many more), else the refusal, else ""."""
        if self.problems:
            more = f" (and {len(self.problems) - 1} more)" if len(self.problems) > 1 else ""
            return f"compensation not accepted: {self.problems[0]}{more}"
        return self.refused


def judge_upload(text: str, current: Compensator, reference: ReferenceLoop,
                 checks: CompensationChecks = CompensationChecks()) -> UploadJudgement:
    """Parse, check (closed schema, bands) and judge a compensator upload against ``current`` on ``reference``."""
    import tomllib

    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        return UploadJudgement([f"invalid TOML: {str(exc).splitlines()[0]}"])
    except RecursionError:
        return UploadJudgement(["invalid TOML: nested too deeply"])
    problems = schema_problems(data, checks)
    if problems:
        return UploadJudgement(problems)
    try:
        candidate = Compensator.loads(text, source="body")
    except (TcmsError, RecursionError, TypeError, ValueError) as exc:
        return UploadJudgement([str(exc).splitlines()[0] if str(exc) else type(exc).__name__])
    problems = plausibility_problems(candidate, checks)
    if problems:
        return UploadJudgement(problems, candidate)
    change = rigidity_change(current, candidate, reference)
    band = checks.max_rigidity_change_pct
    refused = ""
    if not math.isfinite(change):
        refused = f"the compensation leaves no usable rigidity on the {reference.source}"
    elif abs(change) * 100.0 > band:
        refused = (f"the compensation would change the rigidity of the {reference.source} by {change:+.1%} "
                   f"(more than ±{band:g} %); repeat with ?force=true if that is intended")
    return UploadJudgement([], candidate, change, reference.source, refused)

"""The compensator: a chain of correction terms applied to numpy batches, and its inverse for the simulator.

    θ_c = θ − Σ_i term_i(θ, T, t)        θ raw encoder reading (arcsec), T torque (N·m), t time (s)

A term is the encoder's error, positive when the encoder reads too much (``terms``), so it is subtracted.
``apply`` evaluates the chain in one compiled pass over the batch (``kernel``), after sorting the terms once,
when the compensator is built:

* linear terms (offset, scale, torsion) fold into three numbers, θ_c = gain·θ − offset − c_T·T − …, with
  gain = 1 − Σ scale coefficients and c_T = Σ torsion coefficients (″/N·m);
* angle-only periodic terms whose period divides one revolution (the 72″ interpolation error and its harmonics,
  eccentricity, errors that repeat over a revolution) are summed into at most two tables, each over its own
  period: one for periods shorter than ``LONG_PERIOD_MIN_ARCSEC`` (looked up per sample) and one for longer
  periods (folded into gain and offset per block of samples). Each table is within ``tolerance_arcsec``/4 of
  its terms, so the result is within ``tolerance_arcsec``/2 of the exact evaluation at any angle;
* every other term (time-dependent, non-linear in torque, not periodic, or one no table can hold) is evaluated
  directly with numpy and subtracted.

``apply(..., exact=True)`` evaluates every term directly: the reference the tests hold the fast path to.
In both paths a reading that is not finite, or beyond ±``MAX_ABS_ANGLE_ARCSEC``, gives NaN for that sample; a
non-finite torque gives a non-finite result where the chain uses torque; nothing raises or warns.

``encoder_reading`` is the forward direction: what the encoder reads for a true angle, so that ``apply``
recovers the truth (the simulated bench uses it as its measuring chain).
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np
import tomli_w

from tcms_daq.compensation import kernel
from tcms_daq.compensation.geometry import (
    GeometricModel,
    Geometry,
    evaluate_geometry,
    geometry_from_dict,
    load_geometry,
)
from tcms_daq.compensation.kernel import MAX_ABS_ANGLE_ARCSEC, PeriodicTable
from tcms_daq.compensation.terms import Eccentricity, Scale, Term, Torsion, term_from_dict
from tcms_daq.config.loader import read_toml
from tcms_daq.errors import ConfigError, DataFormatError
from tcms_daq.units import ARCSEC_PER_REV

DEFAULT_TOLERANCE_ARCSEC = 1e-3
LONG_PERIOD_MIN_ARCSEC = 3600.0  # periods of 1° and more go to the long-period table (folded per block)
_COMMENSURATE_RTOL = 1e-9  # a period divides a revolution if revolution/period is this close to an integer

__all__ = [
    "DEFAULT_TOLERANCE_ARCSEC",
    "LONG_PERIOD_MIN_ARCSEC",
    "MAX_ABS_ANGLE_ARCSEC",
    "Compensator",
    "encoder_reading",
    "load_compensator",
    "measuring_chain_error",
]


@dataclass(frozen=True)
class FastPath:
    """How ``apply`` evaluates a chain of terms: θ_c = gain·θ − offset − c_T·T − short(θ) − long(θ) − direct.

    gain: 1 − Σ scale coefficients; arcsec_per_nm: c_T, Σ torsion coefficients (″/N·m); offset_arcsec: Σ constant
    errors; short_table, long_table: the tabulated periodic terms (or None); tabulated_terms: the terms in them;
    direct_terms: the terms evaluated one by one with numpy.
    """

    gain: float
    arcsec_per_nm: float
    offset_arcsec: float
    short_table: PeriodicTable | None
    long_table: PeriodicTable | None
    tabulated_terms: tuple[Term, ...]
    direct_terms: tuple[Term, ...]

    @classmethod
    def plan(cls, terms: Sequence[Term], tolerance_arcsec: float) -> FastPath:
        """Sort ``terms`` into the folded linear part, the two periodic tables (each within tolerance/4 of its
        terms; none if tolerance is 0) and the directly evaluated rest."""
        offset_arcsec, per_arcsec, arcsec_per_nm = _linear_sums(terms)
        short_terms: list[tuple[Term, int]] = []
        long_terms: list[tuple[Term, int]] = []
        direct: list[Term] = []
        for term in terms:
            if term.linear_parts() is not None:
                continue
            cycles = _cycles_per_revolution(term) if tolerance_arcsec > 0 else None
            if cycles is None:
                direct.append(term)
            elif ARCSEC_PER_REV / cycles < LONG_PERIOD_MIN_ARCSEC:
                short_terms.append((term, cycles))
            else:
                long_terms.append((term, cycles))
        tables: list[PeriodicTable | None] = []
        tabulated: list[Term] = []
        for group in (short_terms, long_terms):
            table = _tabulate(group, tolerance_arcsec / 4)
            tables.append(table)
            if table is None:
                direct.extend(term for term, _ in group)
            else:
                tabulated.extend(term for term, _ in group)
        return cls(
            gain=1.0 - per_arcsec,
            arcsec_per_nm=arcsec_per_nm,
            offset_arcsec=offset_arcsec,
            short_table=tables[0],
            long_table=tables[1],
            tabulated_terms=tuple(tabulated),
            direct_terms=tuple(direct),
        )

    def compile(self) -> None:
        """Compile (or load from numba's cache) the kernel variant ``apply`` will call."""
        kernel.compile_variant(self.short_table, self.long_table)


def _linear_sums(terms: Sequence[Term]) -> tuple[float, float, float]:
    """(offset_arcsec, per_arcsec, arcsec_per_nm): the sums of the linear terms' c0 + c1·θ + c2·T."""
    offset_arcsec = per_arcsec = arcsec_per_nm = 0.0
    for term in terms:
        parts = term.linear_parts()
        if parts is not None:
            offset_arcsec += parts[0]
            per_arcsec += parts[1]
            arcsec_per_nm += parts[2]
    return offset_arcsec, per_arcsec, arcsec_per_nm


def _cycles_per_revolution(term: Term) -> int | None:
    """How many times an angle-only term repeats per revolution, or None (not angle-only, not periodic, or a
    period that does not divide a revolution)."""
    period = term.angle_period_arcsec() if term.angle_only else None
    if period is None or not period > 0:
        return None
    cycles = ARCSEC_PER_REV / period
    whole = round(cycles)
    if whole < 1 or abs(cycles - whole) > _COMMENSURATE_RTOL * cycles:
        return None
    return whole


def _tabulate(group: list[tuple[Term, int]], max_error_arcsec: float) -> PeriodicTable | None:
    """The sum of the group's terms tabulated over their common period (one revolution / gcd of their cycles)."""
    if not group:
        return None
    terms = [term for term, _ in group]
    period = ARCSEC_PER_REV / math.gcd(*(cycles for _, cycles in group))

    def total(angle_arcsec: np.ndarray) -> np.ndarray:
        return np.sum([term.evaluate(angle_arcsec, 0.0, None) for term in terms], axis=0)

    return kernel.tabulate(total, period, max_error_arcsec)


class Compensator:
    """An immutable chain of correction terms (see the module docstring for the convention and units).

    terms: the chain; uncertainties: per term, its parameters' expanded uncertainties (or None);
    meta: descriptive header of the TOML file; tolerance_arcsec: the fast path's error bound is half of it
    (0: every term evaluated directly).
    """

    __slots__ = ("terms", "uncertainties", "meta", "tolerance_arcsec", "fast_path")

    terms: tuple[Term, ...]
    uncertainties: tuple[dict[str, float] | None, ...]
    meta: MappingProxyType[str, Any]
    tolerance_arcsec: float
    fast_path: FastPath

    def __init__(
        self,
        terms: Sequence[Term] = (),
        *,
        uncertainties: Sequence[dict[str, float] | None] | None = None,
        meta: dict[str, Any] | MappingProxyType[str, Any] | None = None,
        tolerance_arcsec: float = DEFAULT_TOLERANCE_ARCSEC,
    ):
        chain = tuple(terms)
        for term in chain:
            if not isinstance(term, Term):
                raise TypeError(f"not a Term: {term!r}")
        unc = tuple(uncertainties) if uncertainties is not None else (None,) * len(chain)
        if len(unc) != len(chain):
            raise ValueError("one uncertainty entry (or None) per term")
        if not 0 <= tolerance_arcsec < math.inf:
            raise ConfigError("tolerance_arcsec must be a finite number >= 0")
        fast_path = FastPath.plan(chain, float(tolerance_arcsec))
        fast_path.compile()
        for name, value in (
            ("terms", chain),
            ("uncertainties", unc),
            ("meta", MappingProxyType(dict(meta or {}))),
            ("tolerance_arcsec", float(tolerance_arcsec)),
            ("fast_path", fast_path),
        ):
            object.__setattr__(self, name, value)

    def __setattr__(self, name: str, value: object) -> None:
        raise AttributeError(f"a Compensator is immutable (build a new one, e.g. with_terms), cannot set {name!r}")

    def __reduce__(self) -> tuple[Any, ...]:
        return (Compensator.from_dict, (self.to_dict(),))

    # ---- construction ----
    @classmethod
    def identity(cls) -> Compensator:
        """No correction: θ_c = θ."""
        return cls((), meta={"description": "identity (no compensation)"})

    @classmethod
    def from_model(cls, model: GeometricModel, *, eccentricity: bool = True) -> Compensator:
        """Scale (1 − k) and torsion (32 ΔL/(G π d⁴)) from the consistent geometric model; for φ = 0 (k = 1)
        also the Eq. 2 eccentricity term (its direction at reading 0 is the geometry's eccentricity_phase_rad:
        the inspection values do not give it)."""
        g = model.geometry
        terms: list[Term] = [Scale(coefficient=model.scale_coefficient), Torsion(arcsec_per_nm=model.torsion_arcsec_per_nm)]
        if eccentricity and model.untilted and model.eccentricity_abs_mm > 0:
            terms.append(
                Eccentricity(
                    eccentricity_mm=model.eccentricity_abs_mm,
                    radius_mm=g.encoder_radius_mm,
                    phase_rad=g.eccentricity_phase_rad,
                )
            )
        meta = {
            "description": "consistent geometric model (scale k = R1'/R2, torsion 32 dL/(G pi d^4))",
            "source": g.source,
            "k": model.k,
            "delta_l_mm": model.delta_l_mm,
            "phi_rad": model.phi_rad,
        }
        return cls(terms, meta=meta)

    @classmethod
    def from_geometry(cls, geometry: str | Path | Geometry, *, eccentricity: bool = True) -> Compensator:
        """Compensator of the consistent geometric model for a geometry file (or Geometry)."""
        geom = geometry if isinstance(geometry, Geometry) else load_geometry(geometry)
        return cls.from_model(evaluate_geometry(geom), eccentricity=eccentricity)

    def with_terms(self, *terms: Term) -> Compensator:
        """A new compensator with ``terms`` appended (e.g. accepted by the discrepancy workflow)."""
        return Compensator(
            self.terms + tuple(terms),
            uncertainties=self.uncertainties + (None,) * len(terms),
            meta=self.meta,
            tolerance_arcsec=self.tolerance_arcsec,
        )

    # ---- the hot path ----
    def apply(
        self,
        angle_arcsec,
        torque_nm,
        time_s=None,
        *,
        out: np.ndarray | None = None,
        exact: bool = False,
    ) -> np.ndarray:
        """Compensated angle θ_c = θ − Σ term(θ, T, t) in arcsec for raw readings θ (arcsec), torque T (N·m, an
        array of θ's shape or a scalar) and time t (s, needed only by time-dependent terms).

        θ and T may be of any real dtype and memory layout (they are read as float64, C-contiguous: converted
        or copied when they are not). ``out``: a preallocated aligned C-contiguous float64 array of θ's shape
        (it may be θ or T itself). ``exact=True`` evaluates every term directly instead of from the tables
        (which are within tolerance_arcsec/2).
        """
        angle = _as_samples(angle_arcsec)
        shape = angle.shape
        if out is None:
            out = np.empty(shape)
        elif out.shape != shape or out.dtype != np.float64 or not (out.flags.c_contiguous and out.flags.aligned):
            raise ValueError("out must be an aligned C-contiguous float64 array of the angle's shape")
        angle = _unless_overlapping(angle, out)
        angle_flat, out_flat = angle.reshape(-1), out.reshape(-1)
        torque = _torque_samples(torque_nm, shape)
        if isinstance(torque, np.ndarray):
            torque = _unless_overlapping(torque, out_flat)
        time = None if time_s is None else np.broadcast_to(np.asarray(time_s, dtype=float), shape).reshape(-1)
        if exact:
            correction = _sum_of_terms(self.terms, angle_flat, torque, time)
            np.subtract(angle_flat, correction, out=out_flat)
            out_flat[~(np.abs(angle_flat) <= MAX_ABS_ANGLE_ARCSEC)] = np.nan
            return out
        fast = self.fast_path
        # the direct terms first: ``out`` may be the input array itself
        direct = _sum_of_terms(fast.direct_terms, angle_flat, torque, time) if fast.direct_terms else None
        torque_array, arcsec_per_nm, offset_arcsec = angle_flat, 0.0, fast.offset_arcsec
        if isinstance(torque, np.ndarray):
            if fast.arcsec_per_nm != 0.0:
                torque_array, arcsec_per_nm = torque, fast.arcsec_per_nm
        elif fast.arcsec_per_nm != 0.0:  # one torque for the whole batch: fold c_T·T into the offset
            offset_arcsec += fast.arcsec_per_nm * torque
        kernel.compensate(
            angle_flat, torque_array, out_flat, fast.gain, arcsec_per_nm, offset_arcsec,
            fast.short_table, fast.long_table,
        )
        if direct is not None:
            np.subtract(out_flat, direct, out=out_flat)
        return out

    __call__ = apply

    # ---- the forward direction (simulator) ----
    def encoder_reading(
        self, true_angle_arcsec, torque_nm, time_s=None, *, tolerance_arcsec: float = 1e-9, max_iter: int = 100
    ) -> np.ndarray:
        """What the encoder reads (arcsec) for the true angle (arcsec) under this chain's errors: the θ with
        θ − Σ term(θ, T, t) = θ_true. Exact for linear terms, fixed-point iteration for the others."""
        true = np.asarray(true_angle_arcsec, dtype=float)
        torque = np.broadcast_to(np.asarray(torque_nm, dtype=float), true.shape)
        time = None if time_s is None else np.broadcast_to(np.asarray(time_s, dtype=float), true.shape)
        offset_arcsec, per_arcsec, arcsec_per_nm = _linear_sums(self.terms)
        denom = 1.0 - per_arcsec
        if denom <= 0:
            raise ConfigError("scale coefficient >= 1: the measuring chain is not invertible")
        base = true + offset_arcsec + arcsec_per_nm * torque
        nonlinear = [t for t in self.terms if t.linear_parts() is None]
        theta = base / denom
        if not nonlinear:
            return theta
        contraction = sum(t.max_slope() for t in nonlinear) / denom
        if not contraction < 1:
            raise ConfigError("measuring-chain terms change too fast with the angle to invert (|d/dθ| ≥ 1)")
        for _ in range(max_iter):
            extra = np.zeros_like(theta)
            for term in nonlinear:
                extra += term.evaluate(theta, torque, time)
            new = (base + extra) / denom
            if np.max(np.abs(new - theta), initial=0.0) <= tolerance_arcsec:
                return new
            theta = new
        return theta

    def measuring_chain_error(self, true_angle_arcsec, torque_nm, time_s=None) -> np.ndarray:
        """Encoder reading − true angle, in arcsec."""
        true = np.asarray(true_angle_arcsec, dtype=float)
        return self.encoder_reading(true, torque_nm, time_s) - true

    # ---- serialisation ----
    def to_dict(self) -> dict[str, Any]:
        terms = []
        for term, unc in zip(self.terms, self.uncertainties, strict=True):
            d = term.to_dict()
            if unc:
                d["uncertainty"] = dict(unc)
            terms.append(d)
        head = {k: v for k, v in self.meta.items() if v is not None}
        head["tolerance_arcsec"] = self.tolerance_arcsec
        return {"compensator": head, "terms": terms}

    def to_toml(self) -> str:
        return (
            "# TCMS-DAQ compensator: theta_c = theta - sum(term). Angles in arcsec, torque in N m, time in s.\n"
            + tomli_w.dumps(self.to_dict())
        )

    def save(self, path: str | Path) -> None:
        Path(path).write_text(self.to_toml(), encoding="utf-8")

    @classmethod
    def from_dict(cls, data: dict[str, Any], source: str = "<compensator>") -> Compensator:
        head = data.get("compensator", {})
        if not isinstance(head, dict):
            raise ConfigError(f"{source}: [compensator] must be a table")
        raw_terms = data.get("terms", [])
        if not isinstance(raw_terms, list):
            raise ConfigError(f"{source}: 'terms' must be an array of tables ([[terms]])")
        terms, uncs = [], []
        for i, raw in enumerate(raw_terms):
            terms.append(term_from_dict(raw, where=f"{source} terms[{i}]"))
            unc = raw.get("uncertainty") if isinstance(raw, dict) else None
            uncs.append(dict(unc) if isinstance(unc, dict) else None)
        meta = {k: v for k, v in head.items() if k != "tolerance_arcsec"}
        tol = head.get("tolerance_arcsec", DEFAULT_TOLERANCE_ARCSEC)
        if isinstance(tol, bool) or not isinstance(tol, int | float) or not 0 <= tol < math.inf:
            raise ConfigError(f"{source}: tolerance_arcsec must be a finite number >= 0")
        return cls(terms, uncertainties=uncs, meta=meta, tolerance_arcsec=float(tol))

    @classmethod
    def load(cls, path: str | Path) -> Compensator:
        """Load a compensator TOML ([compensator] + [[terms]]) or a geometry TOML ([structure] + [parts.N])."""
        return cls._from_toml_data(read_toml(path), str(path))

    @classmethod
    def loads(cls, text: str, source: str = "<compensator>") -> Compensator:
        """``load`` for TOML text (e.g. an uploaded body); ConfigError naming ``source`` if it does not parse."""
        try:
            data = tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            raise ConfigError(f"{source}: invalid TOML: {exc}") from None
        return cls._from_toml_data(data, source)

    @classmethod
    def _from_toml_data(cls, data: dict[str, Any], source: str) -> Compensator:
        if "structure" in data:
            return cls.from_geometry(geometry_from_dict(data, source=source))
        if "terms" in data or "compensator" in data:
            return cls.from_dict(data, source=source)
        raise ConfigError(f"{source}: neither a compensator ([[terms]]) nor a geometry file ([structure], [parts.N])")

    def __repr__(self) -> str:
        return f"Compensator({[t.label() for t in self.terms]})"

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Compensator) and self.to_dict() == other.to_dict()

    __hash__ = None  # type: ignore[assignment]


def _as_samples(values) -> np.ndarray:
    """``values`` as an aligned C-contiguous float64 array (the array itself when it already is one)."""
    return np.require(values, dtype=np.float64, requirements=("C", "A"))


def _unless_overlapping(samples: np.ndarray, out: np.ndarray) -> np.ndarray:
    """``samples``, or a copy of it when ``out`` overlaps it without being the same memory (writing the result
    would change inputs not read yet)."""
    if np.may_share_memory(samples, out) and samples.ctypes.data != out.ctypes.data:
        return samples.copy()
    return samples


def _torque_samples(torque_nm, shape: tuple[int, ...]) -> np.ndarray | float:
    """Torque (N·m) as a float (one value for the batch) or a flat float64 array of ``shape``'s size."""
    torque = np.asarray(torque_nm, dtype=float)
    if torque.ndim == 0:
        return float(torque)
    if torque.shape != shape:
        try:
            torque = np.broadcast_to(torque, shape)
        except ValueError:
            raise DataFormatError(f"torque shape {torque.shape} does not match angle shape {shape}") from None
    return _as_samples(torque).reshape(-1)


def _sum_of_terms(terms: Sequence[Term], angle: np.ndarray, torque: np.ndarray | float, time: np.ndarray | None) -> np.ndarray:
    """Σ term(θ, T, t) in arcsec, each term evaluated directly (non-finite inputs give NaN, without a warning)."""
    total = np.zeros(angle.shape)
    with np.errstate(invalid="ignore"):
        for term in terms:
            total += term.evaluate(angle, torque, time)
    return total


def load_compensator(path: str | Path) -> Compensator:
    """A compensator from a compensator TOML or a geometry TOML (the bench's ``compensation`` key)."""
    return Compensator.load(path)


def encoder_reading(source: Compensator | str | Path | Geometry, true_angle_arcsec, torque_nm, time_s=None):
    """Forward measuring chain: what the encoder reads (arcsec) for the true angle (arcsec) and torque (N·m)
    under the errors of ``source`` (a Compensator, a geometry or compensator file, or a Geometry)."""
    comp = _as_compensator(source)
    return comp.encoder_reading(true_angle_arcsec, torque_nm, time_s)


def measuring_chain_error(source: Compensator | str | Path | Geometry, true_angle_arcsec, torque_nm, time_s=None):
    """Encoder reading − true angle (arcsec) for the chain described by ``source``."""
    return _as_compensator(source).measuring_chain_error(true_angle_arcsec, torque_nm, time_s)


def _as_compensator(source: Compensator | str | Path | Geometry) -> Compensator:
    if isinstance(source, Compensator):
        return source
    if isinstance(source, Geometry):
        return Compensator.from_geometry(source)
    return Compensator.load(source)

"""The compensator: a chain of correction terms applied to numpy batches, and its inverse for the simulator.

    θ_c = θ − Σ_i term_i(θ, T, t)        (θ raw encoder reading in arcsec, T torque in N·m, t time in s)

``apply`` is vectorised; the fast path is shaped by memory traffic, not by arithmetic:

* all terms that are linear (offset, scale, torsion) collapse into three numbers: θ_c = g·θ − c_T·T − c0
  with g = 1 − s;
* when there are non-linear terms that depend on θ alone (eccentricity, periodic, …), they are summed with the
  offset into one lookup table on a grid of step h ≤ tolerance / max|d Σ/dθ| (a power of two), so the
  nearest grid value differs from the exact sum by at most tolerance/2 (default tolerance 0.001″, far below
  the encoder's 0.7″ resolution). The table is built lazily over the range the data visit and kept for later
  batches; data it cannot cover (non-finite, too wide a range) are evaluated directly; ``exact=True``
  evaluates every term directly;
* the batch is processed in chunks of ``CHUNK`` samples with two preallocated scratch buffers, so θ and T are
  read from memory once, every intermediate stays in the CPU's L2 cache, and the result is written once, by a
  plain copy of the finished chunk (``np.copyto``: a streaming copy does not read the destination first, a
  ufunc writing straight into it does). Per chunk, seven passes: index (2), table gather, c_T·T, add,
  g·θ, subtract — then the copy;
* the table's first and last cells hold a signalling NaN: any sample outside the tabulated range (and any NaN
  or ±inf) lands on one of them (``np.take(mode="clip")``), and the first arithmetic on it raises the IEEE
  invalid flag, which the chunk loop turns into FloatingPointError (``np.errstate(invalid="raise")``) and
  answers by redoing that chunk the careful way (extend the table, or evaluate directly). So the common case
  pays no range check;
* anything else (time-dependent terms, terms registered later) is evaluated directly on the whole batch.

``encoder_reading`` is the forward direction: what the encoder reads for a true angle, so that ``apply``
recovers the truth (used by the simulated bench as its measuring chain).
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import tomli_w

from tcms_daq.compensation.geometry import (
    GeometricModel,
    Geometry,
    evaluate_geometry,
    geometry_from_dict,
    load_geometry,
)
from tcms_daq.compensation.terms import Eccentricity, Scale, Term, Torsion, term_from_dict
from tcms_daq.config.loader import read_toml
from tcms_daq.errors import ConfigError, DataFormatError

CHUNK = 32768  # samples per chunk: θ, T and two scratch buffers (1 MiB) plus the table stay in L2
MAX_TABLE_POINTS = 1 << 22
DEFAULT_TOLERANCE_ARCSEC = 1e-3
# a signalling NaN (quiet bit clear, payload 1): copying it (np.take) keeps it, arithmetic on it raises invalid
_SIGNALLING_NAN_BITS = 0x7FF0000000000001


class _AngleTable:
    """offset + Σ angle-only terms on the grid x_j = (i0 + j)·h (small: it stays in cache).

    h is a power of two, so the index of the nearest grid point needs no multiplication: θ + K with
    K = 1.5·2^52·h lands in a binade whose spacing is exactly h, so the result is K + round(θ/h)·h and its bit
    pattern minus that of K is round(θ/h) (for |θ| < K/3). Positive doubles order like their bit patterns and
    negative ones have the sign bit set, so every θ outside [lo, hi] (and NaN, ±inf) gives an index ≤ 0 or
    ≥ size − 1: the two guard cells, which hold a signalling NaN.
    """

    __slots__ = ("h", "add_const", "bits_offset", "i0", "values", "size", "lo", "hi", "k", "off", "take")

    def __init__(self, terms: Sequence[Term], offset: float, h: float, lo: float, hi: float):
        self.h = h
        self.i0 = math.floor(lo / h) - 2
        self.add_const = 1.5 * 2.0**52 * h
        self.bits_offset = int(np.float64(self.add_const).view(np.int64)) + self.i0
        i1 = math.ceil(hi / h) + 2
        x = (self.i0 + np.arange(i1 - self.i0 + 1, dtype=float)) * h
        values = np.full_like(x, offset)
        for term in terms:
            values += term.evaluate(x, 0.0, None)
        bits = values.view(np.uint64)
        bits[0] = bits[-1] = _SIGNALLING_NAN_BITS
        self.values = values
        self.size = values.size
        self.lo = (self.i0 + 1) * h
        self.hi = (i1 - 1) * h
        # the hot loop's arguments, ready-made: 0-d arrays skip the Python-scalar conversion of every ufunc
        # call and the bound method skips np.take's wrapper (per chunk, not per sample, but it adds up)
        self.k = np.array(self.add_const)
        self.off = np.array(self.bits_offset, dtype=np.int64)
        self.take = values.take

    def lookup_checked(self, th: np.ndarray, u: np.ndarray, out: np.ndarray) -> bool:
        """out ← table at the nearest grid point of each θ (u: scratch); False (out undefined) if any θ is
        outside the table (explicit index check: the slow path must not rely on the guard cells)."""
        idx = u.view(np.int64)
        np.add(th, self.add_const, out=u)
        np.subtract(idx, self.bits_offset, out=idx)
        if idx.size and not (idx.min() >= 1 and idx.max() <= self.size - 2):
            return False
        np.take(self.values, idx, out=out, mode="clip")
        return True


class _Linear:
    """The folded linear terms: θ_c = gain·θ − (z + c_T·T + const), z the tabulated angle-only sum."""

    __slots__ = ("gain", "c_t", "const", "scaled", "has_const")

    def __init__(self, gain: float, c_t: float, const: float):
        self.scaled, self.has_const = gain != 1.0, const != 0.0
        # 0-d arrays: no Python-scalar conversion in every ufunc call
        self.gain, self.c_t, self.const = np.array(gain), np.array(c_t), np.array(const)

    def finish(self, th, tq, z, u, o, have_z: bool) -> None:
        """o ← gain·θ − (z + c_T·T + const) with u as scratch; z is consumed (undefined if not have_z).
        o is written last, by a plain copy (o may alias θ)."""
        if tq is not None:
            if have_z:
                np.multiply(tq, self.c_t, out=u)
                np.add(z, u, out=z)
            else:
                np.multiply(tq, self.c_t, out=z)
                have_z = True
        if self.has_const or not have_z:
            if have_z:
                np.add(z, self.const, out=z)
            else:
                z.fill(self.const)
        if self.scaled:
            np.multiply(th, self.gain, out=u)
            np.subtract(u, z, out=u)
        else:
            np.subtract(th, z, out=u)
        np.copyto(o, u)


class Compensator:
    """An immutable chain of correction terms (see the module docstring for the convention and units)."""

    def __init__(
        self,
        terms: Sequence[Term] = (),
        *,
        uncertainties: Sequence[dict[str, float] | None] | None = None,
        meta: dict[str, Any] | None = None,
        tolerance_arcsec: float = DEFAULT_TOLERANCE_ARCSEC,
    ):
        self.terms: tuple[Term, ...] = tuple(terms)
        for t in self.terms:
            if not isinstance(t, Term):
                raise TypeError(f"not a Term: {t!r}")
        unc = list(uncertainties) if uncertainties is not None else [None] * len(self.terms)
        if len(unc) != len(self.terms):
            raise ValueError("one uncertainty entry (or None) per term")
        self.uncertainties: tuple[dict[str, float] | None, ...] = tuple(unc)
        self.meta: dict[str, Any] = dict(meta or {})
        if not tolerance_arcsec >= 0:
            raise ConfigError("tolerance_arcsec must be >= 0")
        self.tolerance_arcsec = float(tolerance_arcsec)
        c0 = c1 = c2 = 0.0
        tabulable: list[Term] = []
        direct: list[Term] = []
        for t in self.terms:
            parts = t.linear_parts()
            if parts is not None:
                c0 += parts[0]
                c1 += parts[1]
                c2 += parts[2]
            elif t.angle_only and math.isfinite(t.max_slope()):
                tabulable.append(t)
            else:
                direct.append(t)
        self._offset, self._per_arcsec, self._per_nm = c0, c1, c2
        self._tabulable = tuple(tabulable)
        self._direct = tuple(direct)
        slope = sum(t.max_slope() for t in tabulable)
        step = min(self.tolerance_arcsec / slope, 1.0) if slope > 0 else 1.0
        self._table_h = 2.0 ** math.floor(math.log2(step)) if step > 0 else 1.0
        self._table: _AngleTable | None = None

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
        """Compensated angle θ_c = θ − Σ term(θ, T, t) in arcsec for raw readings θ (arcsec), torque T (N·m,
        array of θ's shape or scalar) and time t (s, needed only by time-dependent terms).

        ``out`` may be a preallocated float64 array of θ's shape (it may be θ itself). ``exact=True``
        evaluates the angle-only terms directly instead of from the tabulated sum (≤ tolerance_arcsec/2).
        """
        theta = np.asarray(angle_arcsec, dtype=float)
        shape = theta.shape
        theta_f = np.ascontiguousarray(theta).reshape(-1)
        n = theta_f.size
        torque = np.asarray(torque_nm, dtype=float)
        torque_const = 0.0
        torque_f: np.ndarray | None = None
        if torque.ndim == 0:
            torque_const = float(torque)
        else:
            if torque.shape != shape:
                try:
                    torque = np.broadcast_to(torque, shape)
                except ValueError:
                    raise DataFormatError(
                        f"torque shape {torque.shape} does not match angle shape {shape}"
                    ) from None
            torque_f = np.ascontiguousarray(torque).reshape(-1)
        if out is None:
            out = np.empty(shape)
        elif out.shape != shape or out.dtype != np.float64:
            raise ValueError("out must be a float64 array of the angle's shape")
        if not out.flags.c_contiguous:
            raise ValueError("out must be C-contiguous")
        out_f = out.reshape(-1)
        # direct terms first: ``out`` may be the input array itself
        direct_corr = None
        if self._direct:
            time_f = None if time_s is None else np.broadcast_to(np.asarray(time_s, dtype=float), shape).reshape(-1)
            direct_corr = np.zeros(n)
            for term in self._direct:
                direct_corr += term.evaluate(theta_f, torque_f if torque_f is not None else torque_const, time_f)

        c_t = self._per_nm
        if c_t == 0.0:
            torque_f = None
        angle_terms = bool(self._tabulable)
        # constants not in the table: the offset (when there is no table) and c_T·T for a scalar torque
        const = c_t * torque_const + (0.0 if angle_terms else self._offset)
        lin = _Linear(1.0 - self._per_arcsec, c_t, const)
        use_table = angle_terms and not exact and self.tolerance_arcsec > 0
        size = min(CHUNK, n) or 1
        u = np.empty(size)
        z = np.empty(size)
        idx = u.view(np.int64)
        if not use_table:  # linear terms only, or exact=True: no table, no guard cells
            for s in range(0, n, CHUNK):
                e = min(n, s + CHUNK)
                th, uu, zz = theta_f[s:e], u[: e - s], z[: e - s]
                if angle_terms:
                    self._angle_sum(th, uu, zz, False)
                lin.finish(th, None if torque_f is None else torque_f[s:e], zz, uu, out_f[s:e], angle_terms)
        else:
            add, sub, finish = np.add, np.subtract, lin.finish  # hot loop: no attribute lookups
            caller_err = np.geterr()
            with np.errstate(invalid="raise"):  # a guard cell picked up by np.take raises here
                for s in range(0, n, CHUNK):
                    e = min(n, s + CHUNK)
                    m = e - s
                    th = theta_f[s:e]
                    tq = None if torque_f is None else torque_f[s:e]
                    uu, zz = u[:m], z[:m]
                    table = self._table
                    if table is not None:
                        ii = idx[:m]
                        # round(θ/h) − i0 from the bit pattern of θ + K (see _AngleTable): one add, one subtract
                        add(th, table.k, out=uu)
                        sub(ii, table.off, out=ii)
                        table.take(ii, None, zz, "clip")
                        try:
                            finish(th, tq, zz, uu, out_f[s:e], True)
                            continue
                        except FloatingPointError:  # a guard cell (or inf·0 and the like): redo the chunk
                            pass
                    with np.errstate(**caller_err):  # the careful way, under the caller's error handling
                        self._angle_sum(th, uu, zz, True)
                        lin.finish(th, tq, zz, uu, out_f[s:e], True)
        if direct_corr is not None:
            np.subtract(out_f, direct_corr, out=out_f)
        return out

    __call__ = apply

    def _angle_sum(self, th: np.ndarray, u: np.ndarray, out: np.ndarray, use_table: bool) -> None:
        """Slow path: out ← offset + Σ angle-only terms, from the table (extended over ``th`` if needed) when
        allowed and possible, else evaluated directly (non-finite data, too wide a range, exact=True)."""
        if use_table:
            table = self._table
            if table is not None and table.lookup_checked(th, u, out):
                return
            table = self._extend_table(th)
            if table is not None and table.lookup_checked(th, u, out):
                return
        out.fill(self._offset)
        for term in self._tabulable:
            np.add(out, term.evaluate(th, 0.0, None), out=out)

    def _extend_table(self, th: np.ndarray) -> _AngleTable | None:
        lo = float(th.min())
        hi = float(th.max())
        if not (math.isfinite(lo) and math.isfinite(hi)):
            return None
        table = self._table
        if table is not None:
            lo, hi = min(lo, table.lo), max(hi, table.hi)
        # grow geometrically so a sweep that widens its range rebuilds only a few times
        margin = max(0.5 * (hi - lo), 256 * self._table_h)
        lo, hi = lo - margin, hi + margin
        if (hi - lo) / self._table_h > MAX_TABLE_POINTS:
            return None
        table = _AngleTable(self._tabulable, self._offset, self._table_h, lo, hi)
        self._table = table
        return table

    # ---- the forward direction (simulator) ----
    def encoder_reading(
        self, true_angle_arcsec, torque_nm, time_s=None, *, tolerance_arcsec: float = 1e-9, max_iter: int = 100
    ) -> np.ndarray:
        """What the encoder reads (arcsec) for the true angle (arcsec) under this chain's errors: the θ with
        θ − Σ term(θ, T, t) = θ_true. Exact for linear terms, fixed-point iteration for the others."""
        true = np.asarray(true_angle_arcsec, dtype=float)
        torque = np.broadcast_to(np.asarray(torque_nm, dtype=float), true.shape)
        time = None if time_s is None else np.broadcast_to(np.asarray(time_s, dtype=float), true.shape)
        denom = 1.0 - self._per_arcsec
        if denom <= 0:
            raise ConfigError("scale coefficient >= 1: the measuring chain is not invertible")
        base = true + self._offset + self._per_nm * torque
        nonlinear = self._tabulable + self._direct
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
        if isinstance(tol, bool) or not isinstance(tol, int | float) or not tol >= 0:
            raise ConfigError(f"{source}: tolerance_arcsec must be a number >= 0")
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

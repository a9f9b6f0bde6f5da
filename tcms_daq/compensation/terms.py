"""Correction terms of the compensator and their registry.

Convention (DESIGN §3 item 7): the compensated angle is

    θ_c = θ − Σ_i term_i(θ, T, t)

where θ is the **raw encoder reading** in arcsec (every term sees the raw reading, so the terms add and their
order does not matter), T the measured torque in N·m (positive torque twists the output towards positive
angle) and t the time stamp in s. A term value is the encoder's error in arcsec: positive when the encoder
reads too much.

Adding a term type (e.g. from the discrepancy workflow)::

    @register_term("thermal_drift")
    @dataclass(frozen=True)
    class ThermalDrift(Term):
        rate_arcsec_per_s: float = 0.0
        def evaluate(self, angle_arcsec, torque_nm, time_s): ...

A registered term type round-trips through the compensator TOML (its dataclass fields are the keys).
Terms that are linear in their parameters (``linear_params``) can be fitted by ``calibration``.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from tcms_daq.errors import ConfigError
from tcms_daq.units import ARCSEC_PER_RAD, ARCSEC_PER_REV

TWO_PI = 2.0 * math.pi


class UnknownTermError(ConfigError):
    """A term type name that is not registered."""


class Term:
    """Base class of a correction term (a frozen dataclass in every subclass).

    Class attributes:
      type_name: the registry name (set by ``register_term``);
      angle_only: the value depends on θ alone (the compensator may tabulate it, see ``angle_period_arcsec``);
      time_dependent: needs ``time_s``;
      linear_params: parameter fields the value is linear in (fit by least squares); the remaining fields
        are fixed (e.g. a period) and part of the term's identity.
    """

    __dataclass_fields__: ClassVar[dict[str, Any]]  # every subclass is a dataclass
    type_name: ClassVar[str] = ""
    angle_only: ClassVar[bool] = False
    time_dependent: ClassVar[bool] = False
    linear_params: ClassVar[tuple[str, ...]] = ()

    def evaluate(
        self, angle_arcsec: np.ndarray, torque_nm: np.ndarray | float, time_s: np.ndarray | None
    ) -> np.ndarray:
        """The error in arcsec for raw readings θ (arcsec), torque (N·m: θ's shape or one value), time (s); same
        shape as θ."""
        raise NotImplementedError

    def linear_parts(self) -> tuple[float, float, float] | None:
        """(offset_arcsec, per_arcsec, per_nm) if the term is c0 + c1·θ + c2·T, else None (lets the compensator
        fold all linear terms into three numbers)."""
        return None

    def max_slope(self) -> float:
        """An upper bound of |d term/dθ| (dimensionless); the forward chain uses it to check it can invert."""
        return math.inf

    def angle_period_arcsec(self) -> float | None:
        """For an angle-only term that repeats in θ: its period in arcsec (the compensator tabulates such terms
        over one period when the period divides a revolution); None for a term that does not repeat."""
        return None

    # ---- calibration support: columns of the terms' linear parameters ----
    def design_columns(
        self, angle_arcsec: np.ndarray, torque_nm: np.ndarray, time_s: np.ndarray | None
    ) -> np.ndarray:
        """Matrix (n, len(linear_params)): the term's value is columns @ [param values]."""
        raise NotImplementedError(f"term {self.type_name!r} cannot be fitted linearly")

    def with_params(self, **values: float) -> Term:
        return dataclasses.replace(self, **values)

    def label(self) -> str:
        """A name unique within a compensator (fixed fields distinguish instances, e.g. periodic:72)."""
        return self.type_name

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {"type": self.type_name}
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if value is not None:
                d[f.name] = value
        return d


TERM_TYPES: dict[str, type[Term]] = {}


def register_term(name: str) -> Callable[[type[Term]], type[Term]]:
    """Class decorator: register a Term subclass (a dataclass) under ``name`` for TOML and calibration."""

    def deco(cls: type[Term]) -> type[Term]:
        if not dataclasses.is_dataclass(cls):
            raise TypeError(f"term class {cls.__name__} must be a dataclass")
        if name in TERM_TYPES and TERM_TYPES[name] is not cls:
            raise ValueError(f"term type {name!r} is already registered by {TERM_TYPES[name].__name__}")
        cls.type_name = name
        TERM_TYPES[name] = cls
        return cls

    return deco


def term_from_dict(data: dict[str, Any], where: str = "term") -> Term:
    """Build a term from its TOML table (``type`` plus the dataclass fields). ConfigError on bad input."""
    if not isinstance(data, dict):
        raise ConfigError(f"{where}: must be a table")
    name = data.get("type")
    if name not in TERM_TYPES:
        raise UnknownTermError(f"{where}: unknown term type {name!r} (known: {', '.join(sorted(TERM_TYPES))})")
    cls = TERM_TYPES[name]
    fields = {f.name: f for f in dataclasses.fields(cls)}
    kwargs: dict[str, Any] = {}
    for key, value in data.items():
        if key in ("type", "uncertainty"):
            continue
        if key not in fields:
            raise ConfigError(f"{where}: unknown key {key!r} for term {name!r} (allowed: {', '.join(fields)})")
        numeric = str(fields[key].type) in ("float", "int")
        if isinstance(value, bool) or not isinstance(value, int | float | str) or (
                numeric and not isinstance(value, int | float)):
            raise ConfigError(f"{where}: {key!r} must be a number, got {value!r}")
        if isinstance(value, int | float) and not math.isfinite(value):
            raise ConfigError(f"{where}: {key!r} must be finite")
        kwargs[key] = value
    try:
        term = cls(**kwargs)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{where}: {exc}") from None
    return term


def _as_array(x, like: np.ndarray) -> np.ndarray:
    return np.broadcast_to(np.asarray(x, dtype=float), like.shape)


@register_term("offset")
@dataclass(frozen=True)
class Offset(Term):
    """Constant error: term = value_arcsec."""

    value_arcsec: float = 0.0
    angle_only: ClassVar[bool] = True
    linear_params: ClassVar[tuple[str, ...]] = ("value_arcsec",)

    def evaluate(self, angle_arcsec, torque_nm, time_s):
        return np.full(np.shape(angle_arcsec), self.value_arcsec, dtype=float)

    def linear_parts(self):
        return (self.value_arcsec, 0.0, 0.0)

    def max_slope(self) -> float:
        return 0.0

    def design_columns(self, angle_arcsec, torque_nm, time_s):
        return np.ones((np.size(angle_arcsec), 1))


@register_term("scale")
@dataclass(frozen=True)
class Scale(Term):
    """Scale error: term = coefficient · θ. The geometric model's θ_true = k·θ means coefficient = 1 − k
    (the paper's Δθ = (1 − k)θ); the paper's Table-4 column θ/1.03 is coefficient = 1 − 1/1.03 = 0.02913."""

    coefficient: float = 0.0
    angle_only: ClassVar[bool] = True
    linear_params: ClassVar[tuple[str, ...]] = ("coefficient",)

    def evaluate(self, angle_arcsec, torque_nm, time_s):
        return self.coefficient * np.asarray(angle_arcsec, dtype=float)

    def linear_parts(self):
        return (0.0, self.coefficient, 0.0)

    def max_slope(self) -> float:
        return abs(self.coefficient)

    def design_columns(self, angle_arcsec, torque_nm, time_s):
        return np.asarray(angle_arcsec, dtype=float).reshape(-1, 1)


@register_term("torsion")
@dataclass(frozen=True)
class Torsion(Term):
    """Shaft torsion between the actual and the theoretical measurement point (Eq. 16b):
    term = arcsec_per_nm · T, with arcsec_per_nm = 32 ΔL/(G π d⁴) in ″/N·m (ΔL > 0: the encoder reads more)."""

    arcsec_per_nm: float = 0.0
    linear_params: ClassVar[tuple[str, ...]] = ("arcsec_per_nm",)

    def evaluate(self, angle_arcsec, torque_nm, time_s):
        return self.arcsec_per_nm * _as_array(torque_nm, np.asarray(angle_arcsec))

    def linear_parts(self):
        return (0.0, 0.0, self.arcsec_per_nm)

    def design_columns(self, angle_arcsec, torque_nm, time_s):
        return _as_array(torque_nm, np.asarray(angle_arcsec, dtype=float)).reshape(-1, 1).astype(float)


@register_term("eccentricity")
@dataclass(frozen=True)
class Eccentricity(Term):
    """Once-per-revolution eccentricity error of Eq. 2: term = atan(e sin ψ / (R1 − e cos ψ)) in arcsec with
    ψ = θ[rad] + phase_rad. e = eccentricity_mm, R1 = radius_mm (encoder radius). With phase ≠ 0 the term has
    a constant part at θ = 0 (an offset that no rigidity or lost-motion result sees)."""

    eccentricity_mm: float = 0.0
    radius_mm: float = 30.0
    phase_rad: float = 0.0
    angle_only: ClassVar[bool] = True

    def __post_init__(self) -> None:
        if not self.radius_mm > abs(self.eccentricity_mm):
            raise ValueError("eccentricity term needs radius_mm > |eccentricity_mm|")

    def evaluate(self, angle_arcsec, torque_nm, time_s):
        psi = np.asarray(angle_arcsec, dtype=float) * (1.0 / ARCSEC_PER_RAD) + self.phase_rad
        e = self.eccentricity_mm
        return np.arctan2(e * np.sin(psi), self.radius_mm - e * np.cos(psi)) * ARCSEC_PER_RAD

    def max_slope(self) -> float:
        # d/dψ atan(ε sin ψ/(1 − ε cos ψ)) ≤ ε/(1 − ε); dψ/dθ = 1 (both in rad)
        eps = abs(self.eccentricity_mm) / self.radius_mm
        return eps / (1.0 - eps)

    def angle_period_arcsec(self) -> float:
        return ARCSEC_PER_REV  # once per revolution


@register_term("periodic")
@dataclass(frozen=True)
class Periodic(Term):
    """Periodic error in the encoder angle (e.g. interpolation error at the 72″ signal period):
    term = sin_arcsec · sin(2πθ/P) + cos_arcsec · cos(2πθ/P), P = period_arcsec (fixed)."""

    period_arcsec: float = 72.0
    sin_arcsec: float = 0.0
    cos_arcsec: float = 0.0
    angle_only: ClassVar[bool] = True
    linear_params: ClassVar[tuple[str, ...]] = ("sin_arcsec", "cos_arcsec")

    def __post_init__(self) -> None:
        if not self.period_arcsec > 0:
            raise ValueError("periodic term needs period_arcsec > 0")

    def evaluate(self, angle_arcsec, torque_nm, time_s):
        amp = math.hypot(self.sin_arcsec, self.cos_arcsec)
        phase = math.atan2(self.cos_arcsec, self.sin_arcsec)
        x = np.asarray(angle_arcsec, dtype=float) * (TWO_PI / self.period_arcsec)
        x += phase
        np.sin(x, out=x)
        x *= amp
        return x

    def max_slope(self) -> float:
        return math.hypot(self.sin_arcsec, self.cos_arcsec) * TWO_PI / self.period_arcsec

    def angle_period_arcsec(self) -> float:
        return self.period_arcsec

    def design_columns(self, angle_arcsec, torque_nm, time_s):
        x = np.asarray(angle_arcsec, dtype=float) * (TWO_PI / self.period_arcsec)
        return np.column_stack([np.sin(x), np.cos(x)])

    def label(self) -> str:
        return f"periodic:{self.period_arcsec:g}"


@register_term("drift")
@dataclass(frozen=True)
class Drift(Term):
    """Error growing linearly with time (e.g. thermal drift of the chain): term = arcsec_per_s · t."""

    arcsec_per_s: float = 0.0
    time_dependent: ClassVar[bool] = True
    linear_params: ClassVar[tuple[str, ...]] = ("arcsec_per_s",)

    def evaluate(self, angle_arcsec, torque_nm, time_s):
        if time_s is None:
            raise ConfigError("the drift term needs time_s")
        return self.arcsec_per_s * _as_array(time_s, np.asarray(angle_arcsec))

    def design_columns(self, angle_arcsec, torque_nm, time_s):
        if time_s is None:
            raise ConfigError("the drift term needs a time_s column")
        return _as_array(time_s, np.asarray(angle_arcsec, dtype=float)).reshape(-1, 1).astype(float)


def parse_term_spec(spec: str) -> Term:
    """A term from a command-line name: ``offset``, ``scale``, ``torsion``, ``drift`` or ``periodic:P``
    (P = period in arcsec). Raises UnknownTermError for names that are not registered or not fittable."""
    name, _, arg = spec.strip().partition(":")
    if name not in TERM_TYPES:
        raise UnknownTermError(
            f"unknown term {spec!r} (fittable: offset, scale, torsion, drift, periodic:PERIOD_ARCSEC"
            + "".join(f", {n}" for n in sorted(TERM_TYPES) if n not in _BUILTIN_NAMES)
            + ")"
        )
    cls = TERM_TYPES[name]
    if not cls.linear_params:
        raise UnknownTermError(f"term {name!r} has no linear parameters and cannot be calibrated by least squares")
    if cls is Periodic:
        try:
            period = float(arg)
        except ValueError:
            raise UnknownTermError(f"term {spec!r}: give the period in arcsec, e.g. periodic:72") from None
        if not (period > 0 and math.isfinite(period)):
            raise UnknownTermError(f"term {spec!r}: the period must be > 0")
        return Periodic(period_arcsec=period)
    if arg:
        raise UnknownTermError(f"term {spec!r}: {name!r} takes no argument")
    return cls()


_BUILTIN_NAMES = {"offset", "scale", "torsion", "eccentricity", "periodic", "drift"}

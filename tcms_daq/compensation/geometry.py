"""The geometric error model of the angle-measuring chain (seed paper §2–3, Eqs. 1–16), pure numpy.

Two layers:

1. **As printed** (Eqs. 1, 5, 8 → Eq. 4 with Table 1's decomposition → Eq. 9 → Eq. 14): manufacturing errors
   of the six parts (Table 3) give the assembly errors of the five joints, their first-order error matrices,
   the transform ``T64`` (output-shaft frame S4 in encoder frame S6) and the tilt ``φ`` between the shaft axis
   and the encoder axis. The printed Eqs. 15/16 are evaluated literally as well, for the record only: they take
   square roots of lengths and are dimensionally inconsistent (see ``LiteralEq15``).
2. **Consistent completion** (DESIGN §3 item 4): the shaft axis ``p0 + s·û`` cut by the measurement plane
   ``x6 = x_A`` gives the eccentricity ``e``; the nut (radius R2, normal to û) touches the plane at the actual
   measurement point, so the encoder sees the radius ``R1' = |e + σ (R2/cos φ) ê|`` and the scale
   ``k = R1'/R2`` (true = k · reading), and the measurement point moves along the shaft by
   ``ΔL = s_P + σ R2 tan φ − L47``, adding the shaft torsion ``Δθ_S = 32 T ΔL / (G π d⁴)`` between it and the
   reference point. For φ = 0: k = 1, ΔL = s_P − L47 and the once-per-revolution eccentricity error of Eq. 2.

Units: lengths in mm, angles in rad (the torsion slope is also given in arcsec per N·m). Coordinates: S6, the
encoder axis is x6; positive torque twists the output towards positive angle.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from tcms_daq.config.loader import read_toml
from tcms_daq.errors import ConfigError
from tcms_daq.units import ARCSEC_PER_RAD

JOINTS: tuple[str, ...] = ("1-2", "2-3", "3-4", "1-5", "5-6")
PART_IDS: tuple[int, ...] = (1, 2, 3, 4, 5, 6)
STEEL_SHEAR_MODULUS_PA = 79.3e9
_SIN_PHI_ZERO = 1e-12

_STRUCTURE_KEYS = {
    "l23_mm": "L23, flange (2) to reducer (3) along x",
    "l34_mm": "L34, reducer (3) to output shaft (4)",
    "l15_mm": "L15, platform (1) to encoder flange (5)",
    "l47_mm": "L47, output-shaft origin to the theoretical measurement point",
    "r2_mm": "R2, radius of the coupling nut (measurement point on the shaft)",
    "shaft_diameter_mm": "d, output-shaft diameter (torsion term)",
}
_PART_KEYS = ("dl_mm", "dd_mm", "dtau_rad", "dc_mm")


@dataclass(frozen=True)
class PartErrors:
    """Manufacturing errors of one part (Table 3): length along x, diameter, perpendicularity, coaxiality.

    A blank ("-") in the paper's table is 0.
    """

    dl_mm: float = 0.0
    dd_mm: float = 0.0
    dtau_rad: float = 0.0
    dc_mm: float = 0.0


@dataclass(frozen=True)
class Geometry:
    """Inputs of the model: Table 2 (structure), Table 3 (parts 1…6) and the model options.

    sigma: side of the nut contact (+1 = nut centre on the encoder side, the paper's "+R2 tan φ");
    rotations: "first-order" (Eq. 4 as printed) or "exact" (R = Rz·Ry·Rx);
    measurement_plane_x_mm: x6 of the measurement plane A, default L23 + L34 + L47 − L15 (through the nominal
    measurement point, so every correction vanishes for perfect parts);
    encoder_radius_mm: R1 of Eq. 2 (the paper's RON 786 has 30 mm); eccentricity_phase_rad: angular position of
    the eccentricity at encoder reading 0 (Eq. 2 uses 0).
    """

    l23_mm: float
    l34_mm: float
    l15_mm: float
    l47_mm: float
    r2_mm: float
    shaft_diameter_mm: float
    parts: tuple[PartErrors, ...]
    shear_modulus_pa: float = STEEL_SHEAR_MODULUS_PA
    sigma: int = 1
    rotations: str = "first-order"
    measurement_plane_x_mm: float | None = None
    encoder_radius_mm: float = 30.0
    eccentricity_phase_rad: float = 0.0
    source: str = "<geometry>"

    def part(self, i: int) -> PartErrors:
        return self.parts[i - 1]

    @property
    def plane_x_mm(self) -> float:
        if self.measurement_plane_x_mm is not None:
            return self.measurement_plane_x_mm
        return self.l23_mm + self.l34_mm + self.l47_mm - self.l15_mm


@dataclass(frozen=True)
class AssemblyError:
    """Assembly error of a joint (Eqs. 1, 5, 8): δr along x (mm), eccentricity δe (mm), tilt δt (rad)."""

    dr_mm: float
    de_mm: float
    dt_rad: float


@dataclass(frozen=True)
class LiteralEq15:
    """Eqs. 15–16 evaluated exactly as printed. Dimensionally inconsistent (square roots of lengths, x/y
    components instead of y/z, Eq. 15 and Eq. 16 place −L47 differently): recorded, never used to compensate.
    ``None`` where the printed square root has a negative argument."""

    a: float | None
    pm_o6: float | None
    k: float | None
    pa_pt: float | None
    eq16_bracket: float | None


@dataclass(frozen=True)
class GeometricModel:
    """Result of the model for one geometry. See the module docstring for the symbols."""

    geometry: Geometry
    assembly: dict[str, AssemblyError]
    t64: np.ndarray
    phi_rad: float
    axis_unit: np.ndarray
    origin_mm: np.ndarray
    s_p_mm: float
    eccentricity_mm: np.ndarray
    r1_prime_mm: float
    k: float
    delta_l_mm: float
    literal: LiteralEq15
    notes: list[str] = field(default_factory=list)

    @property
    def torsion_rad_per_nm(self) -> float:
        """Δθ_S per N·m: 32 ΔL / (G π d⁴) in SI units."""
        g = self.geometry
        d_m = g.shaft_diameter_mm * 1e-3
        return 32.0 * (self.delta_l_mm * 1e-3) / (g.shear_modulus_pa * math.pi * d_m**4)

    @property
    def torsion_arcsec_per_nm(self) -> float:
        return self.torsion_rad_per_nm * ARCSEC_PER_RAD

    @property
    def scale_coefficient(self) -> float:
        """The paper's Δθ = (1 − k)·θ coefficient (θ = encoder reading)."""
        return 1.0 - self.k

    @property
    def untilted(self) -> bool:
        """φ = 0 (to rounding): k = 1 and the eccentricity error of Eq. 2 applies."""
        return self.tilt_direction is None

    @property
    def tilt_direction(self) -> np.ndarray | None:
        """ê = (û_y, û_z)/sin φ in the measurement plane (None for φ = 0)."""
        sin_phi = math.sqrt(max(0.0, 1.0 - self.axis_unit[0] ** 2))
        return None if sin_phi < _SIN_PHI_ZERO else self.axis_unit[1:3] / sin_phi

    @property
    def eccentricity_abs_mm(self) -> float:
        return float(np.hypot(*self.eccentricity_mm))

    def to_dict(self) -> dict[str, Any]:
        g = self.geometry
        lit = self.literal
        return {
            "source": g.source,
            "phi_rad": self.phi_rad,
            "phi_arcsec": self.phi_rad * ARCSEC_PER_RAD,
            "t64": [[float(v) for v in row] for row in self.t64],
            "k": self.k,
            "scale_coefficient": self.scale_coefficient,
            "delta_l_mm": self.delta_l_mm,
            "torsion_arcsec_per_nm": self.torsion_arcsec_per_nm,
            "axis_unit": [float(v) for v in self.axis_unit],
            "axis_origin_mm": [float(v) for v in self.origin_mm],
            "tilt_direction": None if self.tilt_direction is None else [float(v) for v in self.tilt_direction],
            "r1_prime_mm": self.r1_prime_mm,
            "s_p_mm": self.s_p_mm,
            "eccentricity_mm": [float(v) for v in self.eccentricity_mm],
            "eccentricity_abs_mm": self.eccentricity_abs_mm,
            "measurement_plane_x_mm": g.plane_x_mm,
            "sigma": g.sigma,
            "rotations": g.rotations,
            "shear_modulus_pa": g.shear_modulus_pa,
            "assembly_errors": {
                j: {"dr_mm": a.dr_mm, "de_mm": a.de_mm, "dt_rad": a.dt_rad} for j, a in self.assembly.items()
            },
            "literal_eq15_16": {
                "a": lit.a,
                "pm_o6": lit.pm_o6,
                "k": lit.k,
                "pa_pt": lit.pa_pt,
                "eq16_bracket": lit.eq16_bracket,
                "note": "printed Eqs. 15-16 evaluated literally; dimensionally inconsistent "
                "(square roots of lengths), not used for compensation",
            },
            "notes": list(self.notes),
        }


# ---------------------------------------------------------------------------------------------------------
# loading


def _float(table: dict, key: str, where: str, default: float | None = None) -> float:
    if key not in table:
        if default is None:
            raise ConfigError(f"{where}: missing key {key!r}")
        return default
    value = table[key]
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ConfigError(f"{where}: {key!r} must be a finite number, got {value!r}")
    return float(value)


def _check_keys(table: dict, allowed: set[str], where: str) -> None:
    unknown = sorted(set(table) - allowed)
    if unknown:
        raise ConfigError(f"{where}: unknown key {unknown[0]!r} (allowed: {', '.join(sorted(allowed))})")


def geometry_from_dict(data: dict[str, Any], source: str = "<geometry>") -> Geometry:
    """Build a Geometry from the TOML layout of ``config/geometry-paper.toml``; ConfigError on bad input."""
    if not isinstance(data.get("structure"), dict):
        raise ConfigError(f"{source}: missing table [structure] (Table 2: {', '.join(_STRUCTURE_KEYS)})")
    st = data["structure"]
    _check_keys(st, set(_STRUCTURE_KEYS) | {"encoder_radius_mm"}, f"{source} [structure]")
    values = {k: _float(st, k, f"{source} [structure]") for k in _STRUCTURE_KEYS}
    for k in ("r2_mm", "shaft_diameter_mm"):
        if values[k] <= 0:
            raise ConfigError(f"{source} [structure]: {k!r} must be > 0")
    encoder_radius_mm = _float(st, "encoder_radius_mm", f"{source} [structure]", 30.0)

    parts_tbl = data.get("parts")
    if not isinstance(parts_tbl, dict):
        raise ConfigError(f"{source}: missing table [parts] with [parts.1] … [parts.6] (Table 3)")
    _check_keys(parts_tbl, {str(i) for i in PART_IDS}, f"{source} [parts]")
    parts = []
    for i in PART_IDS:
        p = parts_tbl.get(str(i), {})
        where = f"{source} [parts.{i}]"
        if not isinstance(p, dict):
            raise ConfigError(f"{where}: must be a table")
        _check_keys(p, set(_PART_KEYS) | {"name"}, where)
        parts.append(PartErrors(*(_float(p, k, where, 0.0) for k in _PART_KEYS)))

    model = data.get("model", {})
    if not isinstance(model, dict):
        raise ConfigError(f"{source}: [model] must be a table")
    allowed_model = {"shear_modulus_pa", "sigma", "rotations", "measurement_plane_x_mm", "eccentricity_phase_rad"}
    _check_keys(model, allowed_model, f"{source} [model]")
    sigma = model.get("sigma", 1)
    if sigma not in (1, -1) or isinstance(sigma, bool):
        raise ConfigError(f"{source} [model]: 'sigma' must be +1 or -1, got {sigma!r}")
    rotations = model.get("rotations", "first-order")
    if rotations not in ("first-order", "exact"):
        raise ConfigError(f"{source} [model]: 'rotations' must be 'first-order' or 'exact', got {rotations!r}")
    g_pa = _float(model, "shear_modulus_pa", f"{source} [model]", STEEL_SHEAR_MODULUS_PA)
    if g_pa <= 0:
        raise ConfigError(f"{source} [model]: 'shear_modulus_pa' must be > 0")
    plane = model.get("measurement_plane_x_mm")
    plane = None if plane is None else _float(model, "measurement_plane_x_mm", f"{source} [model]")
    phase = _float(model, "eccentricity_phase_rad", f"{source} [model]", 0.0)
    return Geometry(
        **values,
        parts=tuple(parts),
        shear_modulus_pa=g_pa,
        sigma=int(sigma),
        rotations=rotations,
        measurement_plane_x_mm=plane,
        encoder_radius_mm=encoder_radius_mm,
        eccentricity_phase_rad=phase,
        source=source,
    )


def load_geometry(path: str | Path) -> Geometry:
    """Read a geometry TOML file (Table 2 in [structure], Table 3 in [parts.N], options in [model])."""
    return geometry_from_dict(read_toml(path), source=str(path))


# ---------------------------------------------------------------------------------------------------------
# Eqs. 1–14 as printed


def assembly_errors(geom: Geometry) -> dict[str, AssemblyError]:
    """Eqs. 5 and 8 as printed: δr12 = δr56 = 0, δr15 = Δl5, |Δd_i − Δd_j| for δe, Δc only from part 2."""
    p = geom.part
    return {
        "1-2": AssemblyError(0.0, abs(p(1).dd_mm - p(2).dd_mm), p(1).dtau_rad + p(2).dtau_rad),
        "2-3": AssemblyError(
            p(2).dl_mm + p(3).dl_mm, abs(p(2).dd_mm - p(3).dd_mm) + p(2).dc_mm, p(2).dtau_rad + p(3).dtau_rad
        ),
        "3-4": AssemblyError(p(3).dl_mm + p(4).dl_mm, abs(p(4).dd_mm - p(3).dd_mm), p(3).dtau_rad + p(4).dtau_rad),
        "1-5": AssemblyError(p(5).dl_mm, abs(p(1).dd_mm - p(5).dd_mm), p(1).dtau_rad + p(5).dtau_rad),
        "5-6": AssemblyError(0.0, abs(p(5).dd_mm - p(6).dd_mm), p(5).dtau_rad + p(6).dtau_rad),
    }


def error_matrix(
    dx: float, dy: float, dz: float, dalpha: float, dbeta: float, dgamma: float, rotations: str = "first-order"
) -> np.ndarray:
    """Eq. 4: the error matrix of a joint (first order as printed, or with exact rotations Rz·Ry·Rx)."""
    m = np.eye(4)
    if rotations == "exact":
        ca, sa = math.cos(dalpha), math.sin(dalpha)
        cb, sb = math.cos(dbeta), math.sin(dbeta)
        cg, sg = math.cos(dgamma), math.sin(dgamma)
        rx = np.array([[1, 0, 0], [0, ca, -sa], [0, sa, ca]])
        ry = np.array([[cb, 0, sb], [0, 1, 0], [-sb, 0, cb]])
        rz = np.array([[cg, -sg, 0], [sg, cg, 0], [0, 0, 1]])
        m[:3, :3] = rz @ ry @ rx
    else:
        m[:3, :3] = [[1.0, -dgamma, dbeta], [dgamma, 1.0, -dalpha], [-dbeta, dalpha, 1.0]]
    m[:3, 3] = (dx, dy, dz)
    return m


def joint_error_matrix(err: AssemblyError, rotations: str = "first-order") -> np.ndarray:
    """Table 1: Δx = δr, Δy = Δz = δe, Δα = 0, Δβ = Δγ = δt (the full value on both axes)."""
    return error_matrix(err.dr_mm, err.de_mm, err.de_mm, 0.0, err.dt_rad, err.dt_rad, rotations)


def _tx(length_mm: float) -> np.ndarray:
    m = np.eye(4)
    m[0, 3] = length_mm
    return m


def chain_t64(geom: Geometry, assembly: dict[str, AssemblyError] | None = None) -> np.ndarray:
    """Eq. 9: T64 = (T15 ΔT15 T56 ΔT56)⁻¹ · T12 ΔT12 T23 ΔT23 T34 ΔT34 (nominal Eqs. 6–7: x-translations)."""
    assembly = assembly or assembly_errors(geom)
    d = {j: joint_error_matrix(a, geom.rotations) for j, a in assembly.items()}
    eye = np.eye(4)
    encoder_side = _tx(geom.l15_mm) @ d["1-5"] @ eye @ d["5-6"]
    shaft_side = eye @ d["1-2"] @ _tx(geom.l23_mm) @ d["2-3"] @ _tx(geom.l34_mm) @ d["3-4"]
    return np.linalg.inv(encoder_side) @ shaft_side


def tilt_angle_rad(t64: np.ndarray) -> float:
    """Eq. 14: angle between a = first column of T64 (not normalised) and n = (1, 0, 0)."""
    a = t64[:3, 0]
    return float(math.acos(max(-1.0, min(1.0, a[0] / float(np.linalg.norm(a))))))


def _sqrt_or_none(x: float) -> float | None:
    return math.sqrt(x) if x >= 0 else None


def literal_eq15(geom: Geometry, t64: np.ndarray, phi_rad: float) -> LiteralEq15:
    """Eqs. 15–16 as printed (for the record; dimensionally inconsistent)."""
    m11, m14, m21, m24 = t64[0, 0], t64[0, 3], t64[1, 0], t64[1, 3]
    if math.sin(phi_rad) < _SIN_PHI_ZERO:
        return LiteralEq15(None, None, None, None, None)
    a = _sqrt_or_none(geom.r2_mm / (m11 * math.sin(phi_rad)) - m14 / m11)
    pm_o6 = None if a is None else math.hypot(a * m11 + m14, a * m21 + m24)
    k = None if pm_o6 is None else pm_o6 / geom.r2_mm
    pa_pt = _sqrt_or_none(geom.r2_mm * math.tan(phi_rad) - m14 / m11 - geom.l47_mm)
    root = _sqrt_or_none(geom.r2_mm * math.tan(phi_rad) - m14 / m11)
    bracket = None if root is None else root - geom.l47_mm
    return LiteralEq15(a, pm_o6, k, pa_pt, bracket)


# ---------------------------------------------------------------------------------------------------------
# consistent completion


def evaluate_geometry(geom: Geometry) -> GeometricModel:
    """Run the printed chain (Eqs. 1–14) and the consistent completion of Eqs. 15–16 for one geometry."""
    assembly = assembly_errors(geom)
    t64 = chain_t64(geom, assembly)
    phi = tilt_angle_rad(t64)
    u = t64[:3, 0] / np.linalg.norm(t64[:3, 0])
    p0 = t64[:3, 3].copy()
    x_a = geom.plane_x_mm
    s_p = (x_a - p0[0]) / u[0]
    ecc = (p0 + s_p * u)[1:3]
    sin_phi = math.sqrt(max(0.0, 1.0 - u[0] * u[0]))
    notes: list[str] = []
    if sin_phi < _SIN_PHI_ZERO:
        k = 1.0
        delta_l = s_p - geom.l47_mm
        r1_prime = geom.r2_mm
        notes.append("phi = 0: k = 1, eccentricity error per Eq. 2")
    else:
        e_hat = u[1:3] / sin_phi
        cos_phi = u[0]
        delta_l = s_p + geom.sigma * geom.r2_mm * (sin_phi / cos_phi) - geom.l47_mm
        r1_prime = float(np.linalg.norm(ecc + geom.sigma * (geom.r2_mm / cos_phi) * e_hat))
        k = r1_prime / geom.r2_mm
    return GeometricModel(
        geometry=geom,
        assembly=assembly,
        t64=t64,
        phi_rad=phi,
        axis_unit=u,
        origin_mm=p0,
        s_p_mm=float(s_p),
        eccentricity_mm=np.asarray(ecc, dtype=float),
        r1_prime_mm=float(r1_prime),
        k=float(k),
        delta_l_mm=float(delta_l),
        literal=literal_eq15(geom, t64, phi),
        notes=notes,
    )


def eccentricity_error_rad(angle_rad, eccentricity_mm: float, radius_mm: float, phase_rad: float = 0.0):
    """Eq. 2: Δθ = atan(e sin ψ / (R1 − e cos ψ)), ψ = θ + phase (rad in, rad out; vectorised)."""
    psi = np.asarray(angle_rad, dtype=float) + phase_rad
    return np.arctan2(eccentricity_mm * np.sin(psi), radius_mm - eccentricity_mm * np.cos(psi))

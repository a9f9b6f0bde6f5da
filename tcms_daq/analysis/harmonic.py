"""Harmonic Drive piecewise torsional stiffness K1, K2, K3 with breakpoints T1, T2.

Harmonic Drive catalogues linearise the torque–torsion curve of one direction, from zero torque, in three
regions: K1 on [0, T1], K2 on [T1, T2], K3 above T2 (N·m/rad). The catalogue angle formula is
``hd_torsion_angle_rad``; the evaluation fits one least-squares line per region to the hysteresis midline.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from tcms_daq.units import ARCSEC_PER_RAD

GRID_POINTS_PER_REGION = 41
MIN_REGION_FRACTION = 0.05  # a region must span at least 5 % of the largest breakpoint to be fitted


def hd_torsion_angle_rad(torque_nm: npt.ArrayLike, t1_nm: float, t2_nm: float, k1_nm_per_rad: float,
                         k2_nm_per_rad: float, k3_nm_per_rad: float) -> Any:
    """Torsion angle (rad) of one direction for |torque| from zero, by the catalogue's three-region formula.

    Odd in torque: a negative torque gives the negative angle. HFUC-32-100 (T1 29, K1 6.7e4, T2 108,
    K2 1.1e5, K3 1.2e5) at 60 N·m: 29/6.7e4 + 31/1.1e5 = 7.15e-4 rad = 2.5′.
    """
    t = np.asarray(torque_nm, dtype=float)
    mag = np.abs(t)
    phi = np.minimum(mag, t1_nm) / k1_nm_per_rad
    phi = phi + np.clip(mag - t1_nm, 0.0, t2_nm - t1_nm) / k2_nm_per_rad
    phi = phi + np.maximum(mag - t2_nm, 0.0) / k3_nm_per_rad
    result = np.sign(t) * phi
    return float(result) if result.ndim == 0 else result


def hd_regions(breakpoints_nm: tuple[float, float], reached_nm: float) -> list[tuple[float, float] | None]:
    """Torque ranges (positive magnitudes) of the K1, K2, K3 regions inside [0, reached]; None if too short."""
    t1, t2 = breakpoints_nm
    if not 0.0 < t1 < t2:
        raise ValueError(f"Harmonic Drive breakpoints must satisfy 0 < T1 < T2, got {breakpoints_nm}")
    min_span = MIN_REGION_FRACTION * t2
    regions: list[tuple[float, float] | None] = []
    for lo, hi in ((0.0, t1), (t1, t2), (t2, reached_nm)):
        hi = min(hi, reached_nm)
        regions.append((lo, hi) if hi - lo >= min_span else None)
    return regions


def region_grid(region: tuple[float, float]) -> np.ndarray:
    return np.linspace(region[0], region[1], GRID_POINTS_PER_REGION)


def stiffness_nm_per_rad(torque_nm: np.ndarray, angle_arcsec: np.ndarray) -> float:
    """Least-squares slope dT/dθ of a line θ = a + T/K fitted to the points, as K in N·m/rad."""
    t = torque_nm - torque_nm.mean()
    compliance_arcsec_per_nm = float(np.dot(t, angle_arcsec - angle_arcsec.mean()) / np.dot(t, t))
    return ARCSEC_PER_RAD / compliance_arcsec_per_nm

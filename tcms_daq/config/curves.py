"""Catalogue curves the configuration's reducer entries state (pure numpy): the Harmonic Drive three-region
torsion curve. Here, below both the configuration models and the analysis, so each can use it without the other."""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

__all__ = ["hd_torsion_angle_rad"]


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

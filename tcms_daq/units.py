"""Unit conversions used everywhere. Angles: arcsec unless a name says otherwise; torque: N·m.

1 arcmin = 60″; K[Nm/rad] = K[Nm/arcmin] × 10800/π.
"""

from __future__ import annotations

import math
from typing import TypeVar

import numpy as np
import numpy.typing as npt

ARCSEC_PER_RAD: float = 180.0 * 3600.0 / math.pi  # 206264.806…″
ARCSEC_PER_DEG: float = 3600.0
ARCSEC_PER_REV: float = 360.0 * ARCSEC_PER_DEG  # 1 296 000″
ARCSEC_PER_ARCMIN: float = 60.0
ARCMIN_PER_RAD: float = 10800.0 / math.pi  # 3437.747…

# a scalar or an array of them: each conversion returns the kind it is given
Quantity = TypeVar("Quantity", float, npt.NDArray[np.float64])


def rad_to_arcsec(angle_rad: Quantity) -> Quantity:
    return angle_rad * ARCSEC_PER_RAD


def arcsec_to_rad(angle_arcsec: Quantity) -> Quantity:
    return angle_arcsec / ARCSEC_PER_RAD


def deg_to_arcsec(angle_deg: Quantity) -> Quantity:
    return angle_deg * ARCSEC_PER_DEG


def arcsec_to_deg(angle_arcsec: Quantity) -> Quantity:
    return angle_arcsec / ARCSEC_PER_DEG


def nm_per_arcmin_to_nm_per_rad(k_nm_per_arcmin: Quantity) -> Quantity:
    return k_nm_per_arcmin * ARCMIN_PER_RAD


def nm_per_rad_to_nm_per_arcmin(k_nm_per_rad: Quantity) -> Quantity:
    return k_nm_per_rad / ARCMIN_PER_RAD


def nm_per_arcmin_to_arcsec_per_nm(k_nm_per_arcmin: Quantity) -> Quantity:
    """Compliance in ″/N·m for a rigidity in N·m/arcmin."""
    return ARCSEC_PER_ARCMIN / k_nm_per_arcmin

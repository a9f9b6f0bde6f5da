"""Encoder error model and compensation (DESIGN §3): the paper's DH chain and its consistent completion
(``geometry``), the correction-term chain applied to batches (``Compensator``, ``terms``; its compiled one-pass
evaluation in ``kernel``), calibration against a reference instrument (``calibration``) and the paper's Table 4
comparison (``table4``)."""

from tcms_daq.compensation import kernel
from tcms_daq.compensation.compensator import (
    Compensator,
    encoder_reading,
    load_compensator,
    measuring_chain_error,
)
from tcms_daq.compensation.geometry import (
    GeometricModel,
    Geometry,
    evaluate_geometry,
    geometry_from_dict,
    load_geometry,
)
from tcms_daq.compensation.terms import (
    TERM_TYPES,
    Drift,
    Eccentricity,
    Offset,
    Periodic,
    Scale,
    Term,
    Torsion,
    UnknownTermError,
    register_term,
    term_from_dict,
)

__all__ = [
    "TERM_TYPES",
    "Compensator",
    "Drift",
    "Eccentricity",
    "GeometricModel",
    "Geometry",
    "Offset",
    "Periodic",
    "Scale",
    "Term",
    "Torsion",
    "UnknownTermError",
    "encoder_reading",
    "kernel",
    "evaluate_geometry",
    "geometry_from_dict",
    "load_compensator",
    "load_geometry",
    "measuring_chain_error",
    "register_term",
    "term_from_dict",
]

"""Test procedures: loading profiles (pure data) and the simple in-process runner for the simulated bench."""

from tcms_daq.procedure.profiles import (
    CONDITIONING,
    OUTSIDE_LOOPS,
    Profile,
    Segment,
    build_profile,
    continuous_profile,
    default_rate_nm_per_s,
    gb_waypoints,
    stepped_profile,
)
from tcms_daq.procedure.runner import evaluated_samples, run_stiffness_test

__all__ = [
    "CONDITIONING",
    "OUTSIDE_LOOPS",
    "Profile",
    "Segment",
    "build_profile",
    "continuous_profile",
    "default_rate_nm_per_s",
    "evaluated_samples",
    "gb_waypoints",
    "run_stiffness_test",
    "stepped_profile",
]

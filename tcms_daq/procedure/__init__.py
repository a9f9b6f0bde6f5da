"""Test procedures as data: loading profiles, and the evaluation of a test against its catalogue entry.

The procedure that runs a profile on a bench is the state machine in ``tcms_daq.acquisition``."""

from tcms_daq.procedure.profiles import (
    CONDITIONING,
    OUTSIDE_LOOPS,
    Profile,
    Segment,
    build_profile,
    check_test_bounds,
    continuous_profile,
    default_rate_nm_per_s,
    gb_waypoints,
    stepped_profile,
)

__all__ = [
    "CONDITIONING",
    "OUTSIDE_LOOPS",
    "Profile",
    "Segment",
    "build_profile",
    "check_test_bounds",
    "continuous_profile",
    "default_rate_nm_per_s",
    "gb_waypoints",
    "stepped_profile",
]

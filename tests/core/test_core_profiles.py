"""Loading profiles (pure data), and a stepped profile run through the test procedure."""

from __future__ import annotations

import numpy as np
import pytest

from tcms_daq.config import TestProfile
from tcms_daq.procedure import (
    CONDITIONING,
    OUTSIDE_LOOPS,
    build_profile,
    continuous_profile,
    gb_waypoints,
    stepped_profile,
)


def test_gb_sequence():
    pts = gb_waypoints(100.0, cycles=2, conditioning_loops=1)
    assert pts[0] == (-100.0, OUTSIDE_LOOPS) and pts[-1] == (0.0, OUTSIDE_LOOPS)
    loops = pts[1:-1]
    assert [t for t, _ in loops] == [0.0, 100.0, 0.0, -100.0] * 3
    assert [i for _, i in loops] == [CONDITIONING] * 4 + [1] * 4 + [2] * 4
    mirrored = gb_waypoints(100.0, cycles=1, start="positive")
    assert [t for t, _ in mirrored] == [100.0, 0.0, -100.0, 0.0, 100.0, 0.0, -100.0, 0.0, 100.0, 0.0]
    with pytest.raises(ValueError):
        gb_waypoints(-1.0, 1)


def test_continuous_profile_duration_and_rate():
    p = continuous_profile(1000.0, 250.0, cycles=3, conditioning_loops=1, tip_dwell_s=0.5)
    # approach 4 s + 4 loops × 16 s + return 4 s, and a dwell at every ±T (1 + 4 × 2)
    assert p.duration_s() == pytest.approx(4 + 64 + 4 + 9 * 0.5)
    assert p.mean_rate_nm_per_s == 250.0
    assert {s.slope_nm_per_s for s in p.segments} == {250.0}
    assert p.to_dict()["kind"] == "continuous" and "segments" not in p.to_dict()


def test_stepped_profile_levels():
    p = stepped_profile(120.0, step_nm=50.0, dwell_s=1.0, rate_nm_per_s=100.0, cycles=1)
    first_loop = [s.target_nm for s in p.segments if s.loop_index == CONDITIONING]
    assert first_loop == [-100.0, -50.0, 0.0, 50.0, 100.0, 120.0, 100.0, 50.0, 0.0, -50.0, -100.0, -120.0]
    approach = [s.target_nm for s in p.segments if s.loop_index == OUTSIDE_LOOPS]
    assert approach[:3] == [-50.0, -100.0, -120.0] and approach[-1] == 0.0
    assert all(s.dwell_s == 1.0 for s in p.segments)
    assert p.mean_rate_nm_per_s == pytest.approx(50.0 / (0.5 + 1.0))


def test_build_profile_defaults_to_rated_torque(catalogue):
    p = build_profile(TestProfile(), catalogue["RV-110E"])
    assert p.test_torque_nm == 1078.0 and p.rate_nm_per_s == pytest.approx(1078.0 / 4)
    assert (p.cycles, p.conditioning_loops) == (3, 1)
    assert build_profile(TestProfile(kind="stepped", max_torque_nm=500), None).kind == "stepped"


def test_stepped_profile_through_the_procedure_dwells_and_marks_loops(catalogue):
    from tcms_daq.cli.run import simulate
    from tcms_daq.config import load_bench_config

    spec = catalogue["RV-60N"]
    profile = stepped_profile(568.0, 100.0, 0.5, 500.0, cycles=1)
    run = simulate(load_bench_config(), spec, profile, seed=1)
    rec = run.record
    idx = rec.extra["loop_index"]
    assert set(np.unique(idx)) == {-1.0, 0.0, 1.0}
    assert np.all(np.diff(idx[idx >= 0]) >= 0)  # loops in order
    applied = rec.extra["applied_torque_nm"]
    on_plateau = np.isclose(np.diff(applied), 0.0, atol=1e-6)
    assert on_plateau.mean() > 0.4  # most of the time is spent dwelling on the steps
    levels = set(np.round(applied[1:][on_plateau]))
    assert levels >= {-500.0, -100.0, 0.0, 100.0, 500.0, 568.0, -568.0}
    assert abs(applied[-1]) < 1.0  # ramped down at the end

"""The procedure state machine on the in-process virtual bench (stand-in physics, simulated clock)."""

from __future__ import annotations

import numpy as np
import pytest

from tcms_daq.acquisition import ProfileRejected, TestRun
from tcms_daq.acquisition.record import TRANSITIONS
from tcms_daq.procedure.profiles import Segment


def secant_rigidity(samples, peak_nm: float) -> float:
    """N·m/arcmin: line fits between 50 % and 95 % of the peak on each side, averaged."""
    t, a = samples.torque_nm, samples.angle_arcsec
    slopes = []
    for sign in (1, -1):
        sel = (sign * t > 0.5 * peak_nm) & (sign * t < 0.95 * peak_nm)
        slopes.append(np.polyfit(t[sel], a[sel], 1)[0])
    # the tanh backlash term is saturated above 150 N·m, so each side's slope is the spring's compliance
    return 60.0 / float(np.mean(slopes))


def test_completed_run_walks_the_states_and_ends_safe(make_bench, profile):
    bench = make_bench()
    record = TestRun(bench, profile, evaluate=lambda s: {"rigidity_nm_per_arcmin": secant_rigidity(s, 300.0)}).run()
    assert record.state == "completed", record.reason
    assert [h.state for h in record.history] == ["preparing", "loading", "evaluating", "completed"]
    for a, b in zip(record.history, record.history[1:], strict=False):
        assert b.state in TRANSITIONS[a.state]
        assert b.time_s >= a.time_s
    assert record.reason is None
    assert record.loader_final["state"] == "SWITCH ON DISABLED"
    assert abs(record.loader_final["torque_actual_nm"]) < 1.0
    # the profile was driven: both peaks reached, every sample stamped in order
    s = record.loading_samples()
    assert s.torque_nm.max() > 290 and s.torque_nm.min() < -290
    assert np.all(np.diff(record.samples.time_s) > 0)
    assert record.evaluation["rigidity_nm_per_arcmin"] == pytest.approx(300.0, rel=0.02)
    # the loader's commands: enable, the setpoints in order, zero, disable
    cmds = bench.loader.commands
    assert cmds[0][0] == "enable" and cmds[-1][0] == "disable"
    targets = [v for c, v, _ in cmds if c == "torque"]
    assert targets[: len(profile.segments)] == [s.target_nm for s in profile.segments]
    assert targets[-1] == 0.0


def test_simulated_clock_runs_the_same_run_deterministically(make_bench, profile):
    a = TestRun(make_bench(seed=3), profile).run()
    b = TestRun(make_bench(seed=3), profile).run()
    assert a.state == b.state == "completed"
    np.testing.assert_array_equal(a.samples.time_s, b.samples.time_s)
    np.testing.assert_array_equal(a.samples.angle_arcsec, b.samples.angle_arcsec)


def test_a_setpoint_beyond_the_drive_limit_is_refused_by_the_drive(make_bench, make_profile):
    """The request's limits are plan_from_request's; a profile handed to TestRun directly meets the drive's own
    limit (the bench limit when the loader names none) as the last guard: nothing beyond it is ever applied."""
    bench = make_bench(max_torque_nm=200.0)
    record = TestRun(bench, make_profile(peak_nm=300.0)).run()
    assert record.state == "aborted" and "outside ±200" in record.reason
    assert record.loader_final["state"] == "SWITCH ON DISABLED"
    assert np.abs(record.samples.torque_nm).max() < 0.1 * 200.0


def test_a_profile_that_is_not_numbers_is_rejected_before_anything_moves(make_bench):
    bench = make_bench()
    with pytest.raises(ProfileRejected, match="segment 0: invalid target nan"):
        TestRun(bench, [Segment(float("nan"), 100.0, 0.0, 1)])
    assert bench.loader.commands == []


def test_abort_request_ramps_down_and_keeps_data(make_bench, profile):
    bench = make_bench()
    seen = []
    run = TestRun(bench, profile, subscribers=[seen.append])
    # abort while loading towards -300 N·m (simulated time 0.8 s), deterministic on the simulated clock
    bench.loader.bench.at(0.8, lambda: run.abort("operator pressed stop"))
    record = run.start().join(timeout=30)
    assert record.state == "aborted"
    assert record.reason == "operator pressed stop"
    assert record.loader_final["state"] == "SWITCH ON DISABLED"
    assert abs(record.loader_final["torque_actual_nm"]) < 1.0
    assert record.samples.torque_nm.min() < -150
    assert len(record.samples) > 100
    assert record.samples.torque_nm[-1] == pytest.approx(0.0, abs=2.0)
    # the subscriber saw every state and the data (lossy queue, but nothing dropped at this pace)
    states = [m.details["state"] for m in seen if m.kind == "event" and m.event == "state"]
    assert states == ["preparing", "loading", "aborted"]
    n_data = sum(len(m.samples) for m in seen if m.kind == "data")
    (stats,) = record.acquisition["subscribers"].values()
    if stats["dropped"] == 0:
        assert n_data == len(record.samples)
    else:
        assert n_data < len(record.samples)



def test_interlocks_table_of_the_config_sets_the_limits(profile, make_spring):
    from tcms_daq.acquisition import compose_bench
    from tcms_daq.acquisition.interlocks import InterlockLimits
    from tcms_daq.config import BenchConfig
    from tcms_daq.config.loader import validate
    from tcms_daq.config.models import InterlocksSection
    from tcms_daq.errors import ConfigError

    inst = {"driver": "virtual", "url": "virtual://sim"}
    data = {"bench": {"max_torque_nm": 2000.0}, "instruments": {"angle": inst, "torque": inst, "loader": inst},
            "interlocks": {"angle_max_arcsec": 40.0, "stale_timeout_s": 0.5}}
    bench = compose_bench(validate(BenchConfig, data, "bench.toml"), physics_factory=lambda _c: make_spring())
    run = TestRun(bench, profile)
    assert run.limits.angle_max_arcsec == 40.0 and run.limits.stale_timeout_s == 0.5
    assert run.limits.rate_window_s == InterlockLimits.rate_window_s  # a key left out keeps the default
    record = run.run()
    assert record.state == "aborted" and "outside the window" in record.reason
    data["interlocks"] = {"angle_maximum": 1.0}
    with pytest.raises(ConfigError, match=r"bench.toml: .*interlocks.angle_maximum"):
        validate(BenchConfig, data, "bench.toml")  # checked once, where the file is read
    # the table's keys are the limits' fields
    assert set(InterlocksSection.model_fields) == set(InterlockLimits.__dataclass_fields__)

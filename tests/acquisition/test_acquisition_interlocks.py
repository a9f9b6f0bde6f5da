"""Every interlock trips a run on the in-process virtual bench: aborted with the reason, loader at zero
torque and disabled, data kept. Faults are injected at a fixed simulated time (deterministic)."""

from __future__ import annotations

import re

import numpy as np
import pytest
from tcms_daq.drivers.base import InstrumentTimeout

from tcms_daq.acquisition import InterlockLimits, TestRun
from tcms_daq.acquisition.interlocks import (
    TorqueRateMonitor,
    check_angle_window,
    check_loader_status,
    check_torque_limit,
)
from tcms_daq.acquisition.testrun import default_limits

FAULT_AT_S = 1.8  # while loading from 0 towards +300 N·m (see the timeline of gb_profile)


def assert_safe_abort(record, reason_part: str, interlock: str | None):
    assert record.state == "aborted", (record.state, record.reason)
    assert reason_part in record.reason
    if interlock is not None:
        assert record.trip["interlock"] == interlock
    assert [h.state for h in record.history][-1] == "aborted"
    assert "loading" in [h.state for h in record.history]
    # data kept: samples up to the trip and through the ramp-down
    assert len(record.samples) > 500
    assert record.samples.time_s[0] < FAULT_AT_S - 1.0
    # the angle stamps are the time base: after an angle fault the record ends at the fault
    assert record.samples.time_s[-1] >= FAULT_AT_S - 0.02


def assert_loader_safe(bench):
    """The loader ended disabled at zero torque (link restored first if the test cut it)."""
    bench.loader.bench.faults.loader_lost = False
    bench.loader.connect()  # the run closed the bench it opened
    status = bench.loader.status()
    assert status.state != "OPERATION ENABLED"
    assert abs(status.torque_actual_nm) < 1.0
    assert not bench.loader.bench.drive_enabled


def runaway(vb, target_nm: float):
    """The drive runs away to ``target_nm`` and ignores further setpoints (only disabling stops it)."""

    def act():
        vb.physics.set_torque_target(target_nm, 600.0)
        vb.physics.set_torque_target = lambda *_args: None

    return act


def run_with_fault(bench, profile, action, **kw):
    bench.loader.bench.at(FAULT_AT_S, action)
    return TestRun(bench, profile, **kw).run()


def test_torque_above_the_reducer_limit(make_bench, profile):
    bench = make_bench()
    vb = bench.loader.bench
    record = run_with_fault(bench, profile, runaway(vb, 400.0), reducer_torque_limit_nm=320.0)
    assert_safe_abort(record, "exceeds the reducer limit ±320", "torque_limit")
    assert_loader_safe(bench)
    assert record.samples.torque_nm.max() < 340  # tripped on the way, not after


def test_torque_above_the_bench_limit(make_bench, profile):
    bench = make_bench(max_torque_nm=350.0)
    vb = bench.loader.bench
    record = run_with_fault(bench, profile, runaway(vb, 500.0))
    assert_safe_abort(record, "exceeds the bench limit ±350", "torque_limit")
    assert record.samples.time_s[-1] > record.trip["time_s"] + 0.2  # recording went on during the ramp-down
    assert_loader_safe(bench)


def test_encoder_fault_mid_test(make_bench, profile):
    bench = make_bench()
    vb = bench.loader.bench
    record = run_with_fault(bench, profile, lambda: setattr(vb.faults, "encoder_fault", True))
    assert_safe_abort(record, "encoder fault", "device_fault")
    assert "angle" in record.reason
    assert_loader_safe(bench)


def test_drive_fault_with_error_code(make_bench, profile):
    bench = make_bench()
    vb = bench.loader.bench
    record = run_with_fault(bench, profile, lambda: vb.inject_drive_fault(0x2310))
    assert_safe_abort(record, "0x2310", "drive_fault")
    assert record.loader_final["fault"] is True
    assert_loader_safe(bench)


def test_heartbeat_loss_is_a_lost_instrument(make_bench, profile):
    bench = make_bench()
    vb = bench.loader.bench
    record = run_with_fault(bench, profile, vb.lose_loader_link)
    assert_safe_abort(record, "lost loader instrument", "lost_instrument")
    assert any("failed" in note for note in record.notes)  # the ramp-down commands could not be sent
    assert_loader_safe(bench)


def test_a_loader_command_without_answer_aborts_naming_the_loader(make_bench, profile):
    """One set-point command that times out (the link otherwise fine): the run cannot go on without its
    setpoint; it ends aborted as a lost loader, not as an anonymous 'instrument error'."""
    bench = make_bench()
    loader, calls = bench.loader, []
    send = loader.set_torque

    def set_torque_once_silent(target_nm, slope_nm_per_s):
        calls.append(target_nm)
        if len(calls) == 2:  # the second segment's setpoint
            raise InstrumentTimeout(loader.name, "write target_torque: no response within 0.5 s")
        return send(target_nm, slope_nm_per_s)

    loader.set_torque = set_torque_once_silent
    record = TestRun(bench, profile).run()
    assert record.state == "aborted", (record.state, record.reason)
    assert record.trip["interlock"] == "lost_instrument"
    assert record.reason.startswith("lost loader instrument: ") and "no response" in record.reason
    # a loader that did not answer is sent no ramp (it may not be there to follow it): it is disabled at once
    assert calls[2:] == [] and any("no ramp to zero commanded" in note for note in record.notes)
    assert_loader_safe(bench)


def test_a_setpoint_the_drive_takes_but_does_not_follow_aborts(make_bench, profile):
    """The drive accepts a setpoint and keeps its torque (its link healthy, its status fresh): a safety event,
    so the run aborts through the safe stop naming the setpoint, not a procedure failure."""
    bench = make_bench()
    loader, calls = bench.loader, []
    send = loader.set_torque

    def set_torque_second_ignored(target_nm, slope_nm_per_s):
        calls.append(target_nm)
        if len(calls) != 2:
            send(target_nm, slope_nm_per_s)

    loader.set_torque = set_torque_second_ignored
    record = TestRun(bench, profile).run()
    assert record.state == "aborted", (record.state, record.reason)
    assert record.trip["interlock"] == "setpoint_not_followed"
    assert record.reason.startswith(f"loader did not follow its setpoint: did not reach {calls[1]:g} N·m")
    assert re.search(r"\(measured -?\d+\.\d N·m\)$", record.reason), record.reason  # a number, not a float's repr
    assert calls[2:] == [0.0]  # the link is fine: the safe stop ramps to zero
    assert_loader_safe(bench)


def test_stale_angle_data(make_bench, profile):
    bench = make_bench()
    vb = bench.loader.bench
    record = run_with_fault(bench, profile, lambda: setattr(vb.faults, "angle_muted", True))
    assert_safe_abort(record, "stale data: no angle reading", "stale_data")
    trip_t = record.trip["time_s"]
    assert trip_t == pytest.approx(FAULT_AT_S + 1.0, abs=0.05)  # the watchdog's 1 s default
    assert_loader_safe(bench)


def test_torque_rate_spike(make_bench, profile):
    bench = make_bench()
    vb = bench.loader.bench
    record = run_with_fault(bench, profile, lambda: setattr(vb.faults, "torque_offset_nm", 300.0))
    assert_safe_abort(record, "torque rate", "torque_rate")
    assert_loader_safe(bench)


def test_angle_window(make_bench, profile):
    bench = make_bench()
    limits = default_limits(bench, profile, angle_min_arcsec=-100.0, angle_max_arcsec=50.0)
    record = TestRun(bench, profile, limits=limits).run()
    assert_safe_abort(record, "outside the window [-100, 50]", "angle_window")
    assert_loader_safe(bench)


def test_abort_request_at_a_known_time(make_bench, profile):
    bench = make_bench()
    run = TestRun(bench, profile)
    bench.loader.bench.at(FAULT_AT_S, lambda: run.abort("stop button"))
    record = run.run()
    assert_safe_abort(record, "stop button", None)
    assert record.trip is None
    assert_loader_safe(bench)


# -- the checks as functions ---------------------------------------------------------------------------
def test_check_functions_report_the_first_violation():
    t = np.arange(5) * 0.1
    lim = InterlockLimits(bench_torque_limit_nm=100.0, reducer_torque_limit_nm=80.0, angle_min_arcsec=-5,
                          angle_max_arcsec=5)
    assert check_torque_limit(t, np.array([0, 50, 79, 81, 120.0]), lim).time_s == pytest.approx(0.3)
    assert "reducer" in check_torque_limit(t, np.array([0, 0, 0, 90, 0.0]), lim).reason
    assert check_torque_limit(t, np.zeros(5), lim) is None
    assert check_angle_window(t, np.array([0, 1, -6, 9, 0.0]), lim).time_s == pytest.approx(0.2)
    assert check_angle_window(t, np.zeros(5), InterlockLimits()) is None


def test_rate_monitor_spans_batches_and_ignores_noise():
    lim = InterlockLimits(torque_rate_limit_nm_per_s=500.0, rate_window_s=0.05)
    mon = TorqueRateMonitor(lim)
    rng = np.random.default_rng(1)
    t = np.arange(0, 1, 0.001)
    ramp = 300.0 * t + rng.normal(0, 0.3, t.size)  # 300 N·m/s with noise: fine
    for part in np.array_split(np.arange(t.size), 7):
        assert mon.check(t[part], ramp[part]) is None
    t2 = 1.0 + np.arange(1, 101) * 0.001
    jump = 300.0 + 300.0 * (t2 - 1.0)
    jump[40:] += 60.0  # a 60 N·m jump: 1200 N·m/s over the 50 ms window
    trip = mon.check(t2, jump)
    assert trip is not None and trip.time_s == pytest.approx(t2[40])


def test_loader_status_fault(make_bench):
    from tcms_daq.drivers.base import LoaderStatus

    assert check_loader_status(LoaderStatus("OPERATION ENABLED", 10.0, False)) is None
    trip = check_loader_status(LoaderStatus("FAULT", 0.0, True, error_code=0x8130, time_s=2.0))
    assert trip.interlock == "drive_fault" and "0x8130" in trip.reason

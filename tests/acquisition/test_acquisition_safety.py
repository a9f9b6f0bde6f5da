"""Safety on every exit, whatever the request: bounded aborts, interlocks that judge the signal, bounded
requests (issue 10). In-process virtual bench; times are the simulated clock."""

from __future__ import annotations

import json

import pytest

from tcms_daq.acquisition import TestRun
from tcms_daq.acquisition.testrun import ProcedureOptions, stop_ramp
from tcms_daq.cli import main
from tcms_daq.config.models import BenchSection, TestProfile
from tcms_daq.procedure import check_test_bounds
from tcms_daq.procedure.profiles import Segment, continuous_profile

ABORT_AT_S = 2.0


def _abort_and_disable_times(bench, record, abort_at_s: float) -> float:
    """Clock seconds from the abort request to the loader's disable command."""
    disables = [t for cmd, _, t in bench.loader.commands if cmd == "disable" and t >= abort_at_s]
    assert disables, bench.loader.commands
    return disables[0] - abort_at_s


@pytest.mark.parametrize("slope_nm_per_s", [0.001, 1e-6])
def test_an_absurdly_slow_profile_aborts_at_once(make_bench, slope_nm_per_s):
    # the old ramp-down waited |target| / rate: 300 N·m at 0.001 N·m/s = 3.5 days
    bench = make_bench()
    run = TestRun(bench, [Segment(300.0, slope_nm_per_s, 0.0, 1)])
    bench.loader.bench.at(ABORT_AT_S, lambda: run.abort("stop button"))
    record = run.run()
    assert record.state == "aborted" and record.reason == "stop button"
    assert _abort_and_disable_times(bench, record, ABORT_AT_S) <= ProcedureOptions().max_stop_s
    assert record.loader_final["state"] != "OPERATION ENABLED"


def test_a_slow_ramp_down_option_is_steepened_to_keep_the_stop_bound(make_bench):
    # at 300 N·m with a 1 N·m/s ramp-down the old stop took 300 s; the bound is 5 s whatever the options
    bench = make_bench()
    options = ProcedureOptions(ramp_down_slope_nm_per_s=1.0)
    run = TestRun(bench, [Segment(300.0, 600.0, 100.0, 1)], options=options)
    bench.loader.bench.at(ABORT_AT_S, lambda: run.abort("stop button"))
    record = run.run()
    assert record.state == "aborted"
    elapsed = _abort_and_disable_times(bench, record, ABORT_AT_S)
    assert elapsed <= options.max_stop_s
    assert abs(record.loader_final["torque_actual_nm"]) < 5.0  # ramped down, not dropped at 300 N·m
    assert elapsed > 1.0  # a ramp, not a cut


def test_stop_ramp_is_steep_enough_and_never_slower_than_asked():
    slope, duration = stop_ramp(500.0, 0.001, 5.0)
    assert duration <= 0.6 * 5.0 + 1e-12 and slope == pytest.approx(500.0 / 3.0)
    assert stop_ramp(-2.0, 100.0, 5.0) == (100.0, 0.02)  # the asked slope is kept when it is steeper
    assert stop_ramp(float("nan"), 10.0, 5.0) == (10.0, 0.0)
    with pytest.raises(ValueError, match="max_stop_s"):
        ProcedureOptions(max_stop_s=float("inf"))


def test_a_small_quasi_static_test_completes_without_a_noise_trip(capsys):
    # 20 N·m at 0.5 N·m/s with 0.3 N·m of sensor noise: the old rate interlock (2·rate + 5 % of peak = 2 N·m/s)
    # tripped on the noise within seconds
    code = main(["run", "--reducer", "HFUC-32-100", "--max-torque", "20", "--rate", "0.5", "--cycles", "1",
                 "--json"])
    out = capsys.readouterr()
    assert code == 0, out.err
    result = json.loads(out.out)
    assert result["n_loops"] == 1 and result["loading_rate_nm_per_s"] == pytest.approx(0.5, rel=0.02)


@pytest.mark.parametrize("fields, torque, message", [
    ({"rate_nm_per_s": 0.001}, 500.0, "rate_nm_per_s 0.001 N·m/s is below the bench's slowest rate 0.05"),
    ({"rate_nm_per_s": 1e-300}, 500.0, "below the bench's slowest rate"),
    ({"rate_nm_per_s": 100_000.0}, 500.0, "exceeds the bench's fastest rate 2000"),
    ({"kind": "stepped", "step_nm": 1e-9}, 500.0, "step_nm 1e-09 N·m is below the bench's smallest step"),
    ({"kind": "stepped", "step_nm": 0.1, "cycles": 100}, 500.0, "makes 2020001 steps"),
    ({"rate_nm_per_s": 0.06, "cycles": 50}, 1000.0, "the test would take"),
])
def test_requests_outside_the_bench_bounds_are_refused_before_building(fields, torque, message):
    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace(".", r"\.")):
        check_test_bounds(TestProfile(**fields), torque, BenchSection())


def test_requests_inside_the_bounds_pass():
    check_test_bounds(TestProfile(rate_nm_per_s=0.5), 20.0, BenchSection())
    check_test_bounds(TestProfile(kind="stepped", step_nm=10.0, dwell_s=0.5), 137.0, BenchSection())


def test_the_cli_refuses_an_absurd_rate_with_one_line(capsys):
    assert main(["run", "--rate", "0.001"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("tcms: error: rate_nm_per_s 0.001 N·m/s is below") and "\n" not in err



def test_a_bug_in_the_acquisition_path_ends_the_run_with_the_reason(make_bench, break_compensation_once):
    """Compensation raising once (a bug) on the stepped clock: the run fails with the error as its reason and
    the next test on the same acquisition completes. (Real time, with worker threads: test_acquisition_e2e.)"""
    from tcms_daq.acquisition import AcquisitionLoop

    bench = make_bench()
    bench.connect()
    break_compensation_once(bench, at_call=40)
    profile = continuous_profile(300.0, 600.0, cycles=1, conditioning_loops=1, tip_dwell_s=0.05)
    acq = AcquisitionLoop(bench)
    try:
        first = TestRun(bench, profile, acquisition=acq).run()
        assert first.state == "failed" and "FloatingPointError: compensation blew up" in first.reason
        second = TestRun(bench, profile, acquisition=acq).run()
        assert second.state == "completed", second.reason
    finally:
        acq.close()
        bench.close()

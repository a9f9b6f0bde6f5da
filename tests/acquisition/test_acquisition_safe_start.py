"""The safe start (issue 22): connecting to a bench reads the loader first; a drive found enabled or under torque is
ramped to zero and disabled, one in FAULT is reported; the report says what was found and done, and a test run on
a bench that could not be made safe fails with that reason."""

from __future__ import annotations

import pytest
from tcms_daq.drivers.base import Disconnected, LoaderStatus
from tcms_daq.drivers.cia402_modbus import CiA402Modbus
from tcms_daq.drivers.testing import driver_for, wait_until

from tcms_daq.acquisition import MonotonicClock, TestRun
from tcms_daq.acquisition.bench import Bench

SPEED = 4.0


def _leave_the_drive_under_torque(pb, torque_nm: float) -> None:
    """Another master (with the drive's watchdog off) enables the drive, loads it and goes away without a word."""
    other = driver_for(CiA402Modbus, f"tcp://127.0.0.1:{pb.ports['modbus']}", comm_timeout_ms=0, torque_slope_nm_per_s=4000.0)
    other.connect()
    other.enable()
    other.set_torque(torque_nm)
    assert wait_until(lambda: abs(pb.physics.latest().applied_torque_nm - torque_nm) < 10.0, timeout_s=10.0)
    other.link.client.close()  # no disable, no disarm: as if its process had been killed


def test_connect_finds_a_drive_under_torque_and_makes_it_safe(protocol_bench, caplog):
    pb = protocol_bench(SPEED, comm_timeout_s=0.0)  # a drive without its own watchdog: only the safe start helps
    _leave_the_drive_under_torque(pb, -800.0)
    bench = pb.compose()
    with caplog.at_level("WARNING", logger="tcms_daq.acquisition.bench"):
        bench.connect()
    try:
        report = bench.safe_start
        assert report is not None and report.safe, report
        assert report.found_state == "OPERATION ENABLED" and report.found_torque_nm < -780.0
        assert report.actions == ["target torque 0 (ramped)", "disabled"]
        assert report.final_state == "SWITCH ON DISABLED" and abs(report.final_torque_nm) <= report.safe_torque_nm
        assert "found OPERATION ENABLED at -8" in report.message
        assert report.message in caplog.text
        # the simulated drive itself (not what the link says): disabled, no torque
        assert pb.sims.drive.state.label == "SWITCH ON DISABLED"
        assert abs(pb.physics.latest().applied_torque_nm) < 20.0
    finally:
        bench.close()


def test_connect_reports_a_drive_in_fault_and_the_next_test_completes(protocol_bench, make_profile):
    pb = protocol_bench(SPEED)
    pb.sims.inject("drive", 0x8130)
    bench = pb.compose()
    record = TestRun(bench, make_profile(300.0, 600.0)).run()  # tcms run's path: the run connects the bench
    assert record.state == "completed", record.reason
    assert any("found FAULT 0x8130" in note and "next test resets the fault" in note for note in record.notes)


class _Stub:
    name = "stub"

    def connect(self) -> None:
        pass

    def close(self) -> None:
        pass


class _StuckLoader(_Stub):
    """A drive that stays enabled under torque: its disable does not go through."""

    name = "stuck drive"

    def status(self) -> LoaderStatus:
        return LoaderStatus("OPERATION ENABLED", 650.0, False)

    def set_torque(self, target_nm: float, slope_nm_per_s: float | None = None) -> None:
        pass

    def disable(self) -> None:
        raise Disconnected(self.name, "link lost")


def test_a_bench_that_cannot_be_made_safe_says_so_and_tcms_run_refuses(make_profile):
    bench = Bench(_Stub(), _Stub(), _StuckLoader(), MonotonicClock(), max_torque_nm=2000.0)
    bench.connect()
    report = bench.safe_start
    assert report is not None and not report.safe
    assert "NOT safe" in report.message and "stuck drive" in report.message and "link lost" in report.message
    bench.close()
    record = TestRun(bench, make_profile(300.0, 600.0)).run()
    assert record.state == "failed" and "NOT safe" in record.reason


@pytest.mark.parametrize("state, torque_nm, safe", [("SWITCH ON DISABLED", 0.5, True), ("FAULT", 0.0, True),
                                                     ("SWITCH ON DISABLED", 25.0, False),
                                                     ("OPERATION ENABLED", 0.0, False)])
def test_what_counts_as_safe(state, torque_nm, safe):
    from tcms_daq.acquisition.bench import is_safe

    assert is_safe(state, torque_nm, 20.0) is safe

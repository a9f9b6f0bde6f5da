"""The simulated CiA 402 drive's safety behaviour (state machine, clamp, quick stop, fault, edge-triggered reset)."""

from __future__ import annotations

import pytest
from tcms_daq.sim.instruments.drive402 import Drive402Model, DriveCommandError

from tcms_daq.protocols.cia402 import state_from_statusword


@pytest.fixture
def drive(spring_physics):
    model = Drive402Model(spring_physics, rated_torque_mnm=1_000_000, torque_slope_permille_per_s=100_000)
    emcys = []
    model.add_emcy_listener(lambda code, reg: emcys.append((code, reg)))
    model.emcys = emcys
    yield model
    model.detach()


def _state(model):
    return state_from_statusword(model.statusword())


def _enable(model):
    model.write_mode(4)
    for cw in (0x06, 0x07, 0x0F):
        model.write_controlword(cw)
    assert _state(model) == "OPERATION ENABLED"
    assert model.statusword() & 0x6F == 0x27


def test_state_walk_and_statuswords(drive):
    assert drive.statusword() == 0x0240
    drive.write_controlword(0x06)
    assert drive.statusword() == 0x0231
    drive.write_controlword(0x07)
    assert drive.statusword() == 0x0233
    drive.write_controlword(0x0F)
    assert drive.statusword() & 0x3FF == 0x0237
    drive.write_controlword(0x07)  # disable operation
    assert _state(drive) == "SWITCHED ON"
    drive.write_controlword(0x00)
    assert _state(drive) == "SWITCH ON DISABLED"
    drive.write_controlword(0x0F)  # enable from SOD is not a transition
    assert _state(drive) == "SWITCH ON DISABLED"


def test_profile_torque_and_clamp(drive, spring_physics):
    _enable(drive)
    drive.write_target_torque(300)  # 30 % of 1000 N·m
    spring_physics.advance(0.2)
    assert drive.torque_actual_permille() == pytest.approx(300, abs=2)
    assert drive.statusword() & 0x0400  # target reached
    drive.write_max_torque(200)
    drive.write_target_torque(500)
    spring_physics.advance(0.2)
    assert drive.torque_actual_permille() == pytest.approx(200, abs=2)  # clamped by 0x6072
    assert drive.statusword() & 0x0800  # internal limit active
    assert drive.position_counts() > 0


def test_quick_stop_ramps_to_zero_then_disables(drive, spring_physics):
    _enable(drive)
    drive.write_target_torque(400)
    spring_physics.advance(0.2)
    drive.write_controlword(0x0B)  # quick stop, enable bits kept
    assert _state(drive) == "QUICK STOP ACTIVE"
    spring_physics.advance(0.5)
    assert abs(drive.torque_actual_permille()) <= 5
    assert _state(drive) == "SWITCH ON DISABLED"


def test_fault_emcy_and_rising_edge_reset(drive, spring_physics):
    _enable(drive)
    drive.write_target_torque(400)
    spring_physics.advance(0.2)
    drive.write_controlword(0x8F)  # bit 7 set while healthy: no effect, but remembered as the previous level
    drive.inject_fault(0x2310)
    assert _state(drive) == "FAULT" and drive.error_code == 0x2310
    assert drive.emcys == [(0x2310, 0x03)]
    spring_physics.advance(0.3)
    assert abs(drive.torque_actual_permille()) <= 5  # torque removed
    drive.write_controlword(0x80)  # bit 7 still high: no rising edge, stays in FAULT
    assert _state(drive) == "FAULT"
    drive.write_controlword(0x00)
    drive.write_controlword(0x80)  # rising edge
    assert _state(drive) == "SWITCH ON DISABLED" and drive.error_code == 0
    assert drive.emcys[-1] == (0x0000, 0)


def test_communication_loss_faults_only_when_enabled(drive):
    drive.communication_lost()
    assert _state(drive) == "SWITCH ON DISABLED"
    _enable(drive)
    drive.communication_lost()
    assert _state(drive) == "FAULT" and drive.error_code == 0x8130


def test_refused_writes(drive):
    with pytest.raises(DriveCommandError):
        drive.write_mode(3)  # profile velocity is not supported (1 and 4 are)
    _enable(drive)
    with pytest.raises(DriveCommandError) as info:
        drive.write_rated_torque(5_000)
    assert info.value.kind == "state"

"""CiA 402 profile position (the moves of a multi-position test) over CANopen and Modbus against the simulated
drive on the simulated bench: the set-point handshake, position actual, target reached, no move under torque,
and disable halting a move."""

from __future__ import annotations

import time
import uuid

import pytest
from tcms_daq.drivers.base import CommandRejected
from tcms_daq.drivers.cia402_canopen import CiA402Canopen
from tcms_daq.drivers.cia402_modbus import CiA402Modbus
from tcms_daq.drivers.testing import driver_for, wait_until
from tcms_daq.sim.bench import SimulatedBench
from tcms_daq.sim.instruments.physics import SharedPhysics
from tcms_daq.sim.instruments.serve import DEFAULT_PORTS, InstrumentSimulators, SimulatorOptions

from tcms_daq.config import BenchConfig, SimConfig


@pytest.fixture
def sims():
    physics = SharedPhysics(SimulatedBench.from_config(
        BenchConfig(sim=SimConfig(torque_noise_nm=0.0, encoder_noise_arcsec=0.0))))
    opts = SimulatorOptions.from_mapping({"ports": dict.fromkeys(DEFAULT_PORTS, 0)},
                                         instruments=("canopen", "modbus"), can_interface="virtual",
                                         can_channel=f"t-{uuid.uuid4().hex[:10]}", heartbeat_ms=50)
    simulators = InstrumentSimulators(physics, opts)
    simulators.start()
    physics.start(speed=4.0)
    yield simulators
    simulators.stop()
    physics.stop()


def _drivers(sims):
    return {
        "canopen": lambda: driver_for(CiA402Canopen, f"virtual://{sims.options.can_channel}", heartbeat_ms=50,
                                         master_heartbeat_ms=50, sdo_timeout_s=1.0),
        "modbus": lambda: driver_for(CiA402Modbus, f"tcp://127.0.0.1:{sims.ports['modbus']}", timeout_s=0.5),
    }


@pytest.mark.parametrize("transport", ["canopen", "modbus"])
def test_move_over_the_protocol(sims, transport):
    with _drivers(sims)[transport]() as drive:
        drive.enable()
        drive.set_torque(300.0, 3000.0)
        assert wait_until(lambda: abs(drive.status().torque_actual_nm - 300.0) < 5.0)
        with pytest.raises(CommandRejected, match="no move under torque"):
            drive.move_to(45.0, 90.0)
        assert sims.drive.mode == 4
        drive.set_torque(0.0, 3000.0)
        assert wait_until(lambda: abs(drive.status().torque_actual_nm) < 2.0)
        drive.move_to(45.0, 90.0)  # 0.5 s of simulated time
        assert sims.drive.mode == 1
        assert wait_until(lambda: not drive.status().moving, timeout_s=5.0)
        assert drive.status().position_deg == pytest.approx(45.0, abs=0.01)
        drive.enable()  # back to profile torque at zero
        assert sims.drive.mode == 4 and not drive.status().moving
        # disable during a move halts the output where it is
        drive.move_to(300.0, 20.0)
        assert wait_until(lambda: drive.status().position_deg > 50.0, timeout_s=5.0)
        drive.disable()
        assert wait_until(lambda: drive.status().state == "SWITCH ON DISABLED")
        halted = drive.status().position_deg
        assert 50.0 < halted < 299.0
        time.sleep(0.3)  # 1.2 s of simulated time: a move still under way would have gone on by 24°
        assert drive.status().position_deg == pytest.approx(halted, abs=0.05)

"""AED torque amplifier driver: transcript tests of the exact bytes, and exchanges with the simulator."""

from __future__ import annotations

import pytest
import serial
from pydantic import ValidationError
from tcms_daq.drivers.aed import AED
from tcms_daq.drivers.base import (
    CommandRejected,
    DeviceFault,
    Disconnected,
    InstrumentTimeout,
    MalformedReply,
    TorqueSource,
)
from tcms_daq.drivers.options import AEDOptions
from tcms_daq.drivers.testing import ScriptedSerial, driver_for

SETUP = [(b";", None), (b"COF3;", b"0\r\n"), (b"NOV2000;", b"0\r\n")]


def test_transcript_setup_measure_tare():
    port = ScriptedSerial(SETUP + [
        (b"MSV?;", b"+0000617\r\n"),
        (b"TAR;", b"0\r\n"),
        (b"TAV?;", b"+0000617\r\n"),  # the tare value, kept to restore the zero after a restart
        (b"MSV?;", b"-0001000\r\n"),
    ])
    aed = driver_for(AED, "socket://bench:4002", nominal_torque_nm=500.0, nominal_output=2000, opener=port.opener,
                     clock=lambda: 3.5)
    aed.connect()
    batch = aed.read()
    assert batch.time_s.tolist() == [3.5]
    assert batch.value[0] == pytest.approx(617 / 2000 * 500.0)
    aed.tare()
    assert aed.read().value[0] == pytest.approx(-250.0)
    port.assert_done()
    assert port.settings["bytesize"] == serial.EIGHTBITS and port.settings["parity"] == serial.PARITY_EVEN


def test_transcript_failures():
    port = ScriptedSerial([(b";", None), (b"COF3;", b"0\r\n"), (b"NOV0;", b"0\r\n"),
                           (b"MSV?;", b"+9999999\r\n"),
                           (b"MSV?;", b"+12x4567\r\n"),
                           (b"MSV?;", b"+0012"),
                           (b"MSV?;", None),
                           (b"TAR;", b"?\r\n")])
    aed = driver_for(AED, "socket://bench:4002", opener=port.opener)
    aed.connect()
    with pytest.raises(DeviceFault, match="AED.*overflow"):
        aed.read()
    with pytest.raises(MalformedReply):
        aed.read()
    with pytest.raises(MalformedReply, match="incomplete"):
        aed.read()
    with pytest.raises(InstrumentTimeout, match="AED"):
        aed.read()
    with pytest.raises(CommandRejected, match="TAR"):
        aed.tare()
    port.assert_done()


def test_invalid_settings_rejected_before_any_byte():
    port = ScriptedSerial([])
    with pytest.raises(ValidationError, match="nominal_output"):
        AED(AEDOptions(url="socket://x:1", nominal_output=1_000_000), opener=port.opener)
    with pytest.raises(ValidationError, match="nominal_torque_nm"):
        AED(AEDOptions(url="socket://x:1", nominal_torque_nm=-5.0), opener=port.opener)
    assert port.opened == 0


def _driver(sims, **kw):
    kw.setdefault("nominal_torque_nm", 2000.0)
    return driver_for(AED, f"socket://127.0.0.1:{sims.ports['aed']}", timeout_s=0.2, reconnect_delay_s=0.05, **kw)


def test_normal_exchange_scaling_and_tare(serial_sims):
    physics = serial_sims.physics
    physics.set_drive_enabled(True)
    physics.set_torque_target(300.0, 1e6)
    physics.advance(0.2)
    with _driver(serial_sims, nominal_output=20000) as aed:
        assert isinstance(aed, TorqueSource)
        assert serial_sims.aed.nov == 20000
        assert aed.read().value[0] == pytest.approx(physics.latest().torque_nm, abs=0.1)
        aed.tare()
        assert aed.read().value[0] == pytest.approx(0.0, abs=0.1)
        physics.set_torque_target(400.0, 1e6)
        physics.advance(0.2)
        assert aed.read().value[0] == pytest.approx(100.0, abs=0.2)


def test_timeout_malformed_fault(serial_sims):
    with _driver(serial_sims) as aed:
        for fault, error in (("mute", InstrumentTimeout), ("garbage", MalformedReply),
                             ("partial", MalformedReply), ("sensor_fault", DeviceFault)):
            serial_sims.inject("aed", fault)
            with pytest.raises(error) as info:
                aed.read()
            assert info.value.instrument == "AED"
        serial_sims.inject("aed", None)
        assert len(aed.read()) == 1


def test_reconnect_after_restart_reconfigures(serial_sims):
    with _driver(serial_sims, nominal_output=5000) as aed:
        aed.read()
        serial_sims.restart("aed")  # the amplifier powers up with NOV 0
        assert serial_sims.aed.nov == 0
        aed.read()
        assert serial_sims.aed.nov == 5000  # configuration re-sent after the reconnect
        serial_sims.stop_server("aed")
        with pytest.raises(Disconnected, match="AED"):
            aed.read()


def test_a_restart_restores_the_zero_before_the_next_reading(serial_sims):
    """A power-cycled amplifier comes up untared: the driver writes its last tare value back (TAV) before the
    next MSV?, so the readings after the restart count from the same zero."""
    serial_sims.aed.torque_nm = serial_sims.aed.filtered_nm = lambda: 123.4  # TAR takes the filtered value
    with _driver(serial_sims) as aed:
        aed.tare()
        tared = serial_sims.aed.tare_nm
        assert tared == pytest.approx(123.4, abs=0.01)
        assert aed.read().value[0] == pytest.approx(0.0, abs=0.01)
        serial_sims.restart("aed")
        assert serial_sims.aed.tare_nm == 0.0  # power-on: no tare
        assert aed.read().value[0] == pytest.approx(0.0, abs=0.01)
        assert serial_sims.aed.tare_nm == pytest.approx(tared, abs=0.01)

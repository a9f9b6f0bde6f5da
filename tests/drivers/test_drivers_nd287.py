"""ND 287 driver: transcript tests of the exact bytes, and exchanges with the simulator over socket://."""

from __future__ import annotations

import pytest
import serial
from tcms_daq.drivers.base import AngleSource, DeviceFault, Disconnected, InstrumentTimeout, MalformedReply
from tcms_daq.drivers.nd287 import ND287, parse_frame
from tcms_daq.drivers.testing import ScriptedSerial, driver_for

from tcms_daq.protocols.nd287 import deg_to_dms_packed, dms_to_deg, format_frame

# -- transcripts --------------------------------------------------------------------------------------------

# what the driver sends on connecting (and after a re-open): DC1 (output released), ENQ (the error text, none)
CONNECT = [(b"\x11", None), (b"\x05", b"\x02" + b" " * 13 + b"\r\n")]


def test_transcript_request_and_frame_bytes():
    port = ScriptedSerial([*CONNECT, (b"\x02", b"-  12.34560 G  \r\n"), (b"\x02", b"+   0.00100 G  \r\n")])
    times = iter([10.0, 10.5])
    nd = driver_for(ND287, "socket://bench:4001", opener=port.opener, clock=lambda: next(times))
    nd.connect()
    batch = nd.read()
    assert batch.time_s.tolist() == [10.0]
    assert batch.value[0] == pytest.approx(-12.3456 * 3600.0)
    assert nd.read().value[0] == pytest.approx(3.6)
    port.assert_done()
    # all serial settings go to the constructor: 7 data bits, even parity, 2 stop bits
    assert port.settings["bytesize"] == serial.SEVENBITS
    assert port.settings["parity"] == serial.PARITY_EVEN
    assert port.settings["stopbits"] == serial.STOPBITS_TWO
    assert port.settings["timeout"] == 0.5


def test_transcript_fault_unit_and_garbage_and_silence():
    port = ScriptedSerial([
        *CONNECT,
        (b"\x02", b"+  12.34560 ?  \r\n"),
        (b"\x02", b"+  12.3x560 G  \r\n"),
        (b"\x02", b"+   12.34"),
        (b"\x02", None),
    ])
    nd = driver_for(ND287, "socket://bench:4001", opener=port.opener)
    nd.connect()
    with pytest.raises(DeviceFault, match="ND 287.*encoder fault"):
        nd.read()
    with pytest.raises(MalformedReply, match="ND 287"):
        nd.read()
    with pytest.raises(MalformedReply, match="incomplete"):
        nd.read()
    with pytest.raises(InstrumentTimeout, match="ND 287: no reply"):
        nd.read()
    port.assert_done()


def test_frame_format_units_round_trip():
    frame = format_frame(-12.3456 * 3600.0, decimals=4)
    assert frame == b"-   12.3456 G  \r\n" and len(frame) == 17
    for unit, decimals in (("G", 5), ("R", 8), ("M", 6)):  # resolutions 0.036″, 0.002″, 0.01″
        for angle in (0.0, 1.23, -456.789, 98765.4):
            frame = format_frame(angle, unit=unit, decimals=decimals)
            assert parse_frame(frame) == pytest.approx(angle, abs=0.05)
    assert dms_to_deg(12.3015) == pytest.approx(12 + 30 / 60 + 15 / 3600)
    assert deg_to_dms_packed(12 + 30 / 60 + 15 / 3600) == pytest.approx(12.3015)
    with pytest.raises(MalformedReply):
        parse_frame(b"+   12.7015 M  \r\n")  # 70 minutes
    with pytest.raises(MalformedReply):
        parse_frame(b"+   12.0000 X  \r\n")


# -- against the simulator ----------------------------------------------------------------------------------

def _driver(sims, **kw):
    return driver_for(ND287, f"socket://127.0.0.1:{sims.ports['nd287']}", timeout_s=0.2, reconnect_delay_s=0.05, **kw)


def test_normal_exchange_follows_physics(serial_sims):
    physics = serial_sims.physics
    with _driver(serial_sims) as nd:
        assert isinstance(nd, AngleSource)
        first = nd.read()
        physics.set_drive_enabled(True)
        physics.set_torque_target(500.0, 1e6)
        physics.advance(0.2)
        second = nd.read()
    assert len(first) == 1 and first.value[0] == pytest.approx(0.0, abs=0.05)
    assert second.value[0] == pytest.approx(physics.latest().angle_arcsec, abs=0.05)
    assert second.value[0] > 90.0  # 500 N·m / 5 N·m/″
    assert second.time_s[0] > first.time_s[0]


def test_timeout_when_muted_then_recovers(serial_sims):
    with _driver(serial_sims) as nd:
        serial_sims.inject("nd287", "mute")
        with pytest.raises(InstrumentTimeout, match="ND 287"):
            nd.read()
        serial_sims.inject("nd287", None)
        assert len(nd.read()) == 1


def test_malformed_garbage_and_partial(serial_sims):
    with _driver(serial_sims) as nd:
        serial_sims.inject("nd287", "garbage")
        with pytest.raises(MalformedReply):
            nd.read()
        serial_sims.inject("nd287", "partial")
        with pytest.raises(MalformedReply, match="incomplete"):
            nd.read()
        serial_sims.inject("nd287", None)
        assert len(nd.read()) == 1


def test_encoder_fault(serial_sims):
    with _driver(serial_sims) as nd:
        serial_sims.inject("nd287", "encoder_fault")
        with pytest.raises(DeviceFault) as info:
            nd.read()
        assert info.value.instrument == "ND 287"


def test_reconnect_after_simulator_restart(serial_sims):
    with _driver(serial_sims) as nd:
        nd.read()
        serial_sims.restart("nd287")
        assert len(nd.read()) == 1  # transparently re-opened
        assert nd.link.reconnects == 1


def test_a_power_cycle_loses_the_datum_and_the_driver_counts_a_new_one(serial_sims):
    """The simulated display counts from 0 where it is switched on (its datum is lost, its settings are the
    power-on ones); the driver re-initialises it and tags the readings after it with a new datum."""
    physics, server = serial_sims.physics, serial_sims.nd287
    physics.set_drive_enabled(True)
    physics.set_torque_target(500.0, 1e6)
    physics.advance(0.2)
    with _driver(serial_sims) as nd:
        before = nd.read()
        assert before.extra["angle_datum"].tolist() == [0.0]
        assert before.value[0] == pytest.approx(physics.latest().angle_arcsec, abs=0.05) and before.value[0] > 90.0
        server.unit, server.decimals = "R", 8  # changed at the display since it was switched on
        serial_sims.restart("nd287")
        after = nd.read()
        assert after.extra["angle_datum"].tolist() == [1.0] and nd.power_cycles == 1
        assert after.value[0] == pytest.approx(0.0, abs=0.05)  # counts from where it was switched on
        assert (server.unit, server.decimals) == ("G", 5)  # the power-on settings
        physics.set_torque_target(0.0, 1e6)
        physics.advance(0.2)
        assert nd.read().value[0] == pytest.approx(physics.latest().angle_arcsec - before.value[0], abs=0.1)


def test_disconnected_when_simulator_stays_down(serial_sims):
    with _driver(serial_sims, reconnect_attempts=2) as nd:
        nd.read()
        serial_sims.stop_server("nd287")
        with pytest.raises(Disconnected, match="ND 287.*2 reconnect attempts"):
            nd.read()
        serial_sims.start_server("nd287")
        assert len(nd.read()) == 1

"""CiA 402 loader over Modbus TCP/RTU: exact ADU bytes, exchanges with the simulated drive, failures."""

from __future__ import annotations

import socket
import time
from pathlib import Path

import pytest
from tcms_daq.drivers.base import (
    CommandRejected,
    DeviceFault,
    Disconnected,
    InstrumentTimeout,
    Loader,
    MalformedReply,
)
from tcms_daq.drivers.cia402_modbus import CiA402Modbus
from tcms_daq.drivers.modbus_rtu import RtuSerialClient, inter_frame_silence_s, rtu_reply_length
from tcms_daq.drivers.testing import ManualTime, driver_for, wait_until
from tcms_daq.sim.instruments.proxy import FaultProxy

from tcms_daq.config.loader import packaged_config_dir as tcms_config_dir
from tcms_daq.errors import ConfigError
from tcms_daq.protocols.modbus_map import load_register_map


@pytest.fixture
def drive_sims(make_sims):
    sims = make_sims(instruments=("modbus", "modbus_rtu"))
    sims.physics.start(speed=1.0)
    return sims


def _tcp(sims, port=None, **kw):
    kw.setdefault("timeout_s", 0.3)
    kw.setdefault("reconnect_delay_s", 0.05)
    return driver_for(CiA402Modbus, f"tcp://127.0.0.1:{port or sims.ports['modbus']}", **kw)


def test_register_map_file():
    regmap = load_register_map()
    assert regmap["controlword"].address == 0x3100 and regmap["statusword"].address == 0x3200
    assert regmap["position_actual"].address == 0x3700 and regmap["position_actual"].words == 2
    assert regmap["rated_torque"].address == 0x3C06
    # 32-bit values low word first
    assert regmap.encode("position_actual", 0x00085555) == [0x5555, 0x0008]
    assert regmap.decode("position_actual", [0xFFFE, 0xFFFF]) == -2
    assert regmap.encode("target_torque", -1) == [0xFFFF]


def test_register_map_errors(tmp_path):
    bad = tmp_path / "map.toml"
    bad.write_text('[registers]\ncontrolword = { address = 0x3100, type = "uint16" }\n')
    with pytest.raises(ConfigError, match="lacks statusword"):
        load_register_map(bad)
    bad.write_text('[modbus]\nword_order = "middle"\n')
    with pytest.raises(ConfigError, match="word_order"):
        load_register_map(bad)


def test_adu_bytes_tcp_and_rtu(drive_sims):
    sent = []
    trace = lambda sending, data: (sent.append(bytes(data)) if sending else None, data)[1]  # noqa: E731
    with _tcp(drive_sims, trace_packet=trace) as drive:
        drive.enable()
    pdus = [pkt[6:] for pkt in sent]  # strip the MBAP transaction/protocol/length
    assert all(pkt[2:4] == b"\x00\x00" for pkt in sent)  # protocol id 0
    assert bytes.fromhex("00 06 01 06 31 00 00 06") in [pkt[4:] for pkt in sent]  # length 6, unit 1, write 0x3100
    assert pdus[0] == bytes.fromhex("01 03 3C 06 00 02")  # read rated torque (2 words)
    writes = [p for p in pdus if p[1] == 0x06 and p[2:4] == b"\x31\x00"]
    assert [w[4:] for w in writes] == [b"\x00\x06", b"\x00\x07", b"\x00\x0f"]
    assert bytes.fromhex("01 06 35 00 00 04") in pdus  # mode 4

    sent.clear()
    rtu = driver_for(CiA402Modbus, f"socket://127.0.0.1:{drive_sims.ports['modbus_rtu']}", timeout_s=0.3, trace_packet=trace)
    with rtu:
        rtu.disable()
        rtu.enable()
    # the Kinco manual's own example frame: enable operation = 01 06 31 00 00 0F C7 32 (CRC low byte first)
    assert bytes.fromhex("01 06 31 00 00 0F C7 32") in sent
    assert bytes.fromhex("01 03 32 00 00 01 8A B2") in sent  # read statusword


def test_raw_socket_replies_and_exceptions(drive_sims):
    with socket.create_connection(("127.0.0.1", drive_sims.ports["modbus"]), timeout=2) as sock:
        def ask(hex_request: str) -> bytes:
            sock.sendall(bytes.fromhex(hex_request))
            return sock.recv(256)

        # statusword in SWITCH ON DISABLED: 0x0240
        assert ask("00 07 00 00 00 06 01 03 32 00 00 01") == bytes.fromhex("00 07 00 00 00 05 01 03 02 02 40")
        # unmapped address -> exception 2; write to the read-only statusword -> exception 2
        assert ask("00 08 00 00 00 06 01 03 40 00 00 01") == bytes.fromhex("00 08 00 00 00 03 01 83 02")
        assert ask("00 09 00 00 00 06 01 06 32 00 00 01") == bytes.fromhex("00 09 00 00 00 03 01 86 02")
        # unsupported mode (3 = profile velocity; 1 and 4 are supported) -> exception 3
        assert ask("00 0A 00 00 00 06 01 06 35 00 00 03") == bytes.fromhex("00 0A 00 00 00 03 01 86 03")


def test_normal_exchange_torque_follows(drive_sims):
    with _tcp(drive_sims, torque_slope_nm_per_s=10000.0) as drive:
        assert isinstance(drive, Loader)
        assert drive.rated_torque_nm == pytest.approx(2000.0)
        drive.enable()
        assert drive.status().state == "OPERATION ENABLED"
        drive.set_torque(300.0, slope_nm_per_s=20000.0)
        assert wait_until(lambda: abs(drive.status().torque_actual_nm - 300.0) <= 2.0)
        status = drive.status()
        assert not status.fault and status.position_counts > 0  # positive torque twists positive
        drive.set_torque(-150.0)  # the default slope of the driver (10 kN·m/s)
        assert wait_until(lambda: abs(drive.status().torque_actual_nm + 150.0) <= 2.0)
        drive.disable()
        assert drive.status().state == "SWITCH ON DISABLED"
        assert abs(drive_sims.physics.latest().applied_torque_nm) < 20.0


def test_commands_validated_before_any_byte(drive_sims):
    sent = []
    trace = lambda sending, data: (sent.append(data) if sending else None, data)[1]  # noqa: E731
    with _tcp(drive_sims, max_torque_nm=500.0, trace_packet=trace) as drive:
        drive.enable()
        n = len(sent)
        for bad in (500.1, -600.0, float("nan"), float("inf")):
            with pytest.raises(CommandRejected, match="Modbus"):
                drive.set_torque(bad)
        with pytest.raises(CommandRejected, match="slope"):
            drive.set_torque(100.0, slope_nm_per_s=0.0)
        assert len(sent) == n
        assert drive_sims.drive.max_torque_permille == 250  # 500 N·m of 2000 N·m rated


def test_timeout_when_muted(drive_sims):
    with _tcp(drive_sims) as drive:
        drive_sims.inject("modbus", "mute")
        with pytest.raises(InstrumentTimeout, match="Modbus.*no response"):
            drive.status()
        drive_sims.inject("modbus", None)
        assert drive.status().state == "SWITCH ON DISABLED"


@pytest.mark.parametrize("framing", ["tcp", "rtu"])
def test_malformed_and_partial_replies(drive_sims, framing):
    upstream = drive_sims.ports["modbus" if framing == "tcp" else "modbus_rtu"]
    proxy = FaultProxy("127.0.0.1", upstream)
    port = drive_sims.loop.run(proxy.start())
    url = f"tcp://127.0.0.1:{port}" if framing == "tcp" else f"socket://127.0.0.1:{port}"
    try:
        with driver_for(CiA402Modbus, url, timeout_s=0.3) as drive:
            proxy.inject("garbage")
            with pytest.raises(MalformedReply, match="do not form a valid frame"):
                drive.status()
            proxy.inject("partial")
            with pytest.raises(MalformedReply, match="do not form a valid frame"):
                drive.status()
            proxy.inject(None)
            time.sleep(0.05)
            assert drive.status().state == "SWITCH ON DISABLED"  # the stream resynchronises
    finally:
        drive_sims.loop.run(proxy.stop())


def test_reconnect_after_restart_and_disconnected(drive_sims):
    with _tcp(drive_sims, reconnect_attempts=2) as drive:
        drive.status()
        drive_sims.restart("modbus")
        assert drive.status().state == "SWITCH ON DISABLED"
        assert drive.link.reconnects == 1
        drive_sims.stop_server("modbus")
        with pytest.raises(Disconnected, match="Modbus.*2 reconnect attempts"):
            drive.status()


def test_device_fault_and_reset(drive_sims):
    with _tcp(drive_sims) as drive:
        drive.enable()
        drive.set_torque(200.0, slope_nm_per_s=20000.0)
        drive_sims.inject("drive", 0x2310)
        status = drive.status()
        assert status.fault and status.state == "FAULT" and status.error_code == 0x2310
        with pytest.raises(DeviceFault, match="0x2310") as info:
            drive.enable()
        assert info.value.code == 0x2310
        drive.fault_reset()
        assert drive.status().state == "SWITCH ON DISABLED"
        drive.enable()
        assert drive.status().state == "OPERATION ENABLED"


WATCHDOG_MS = 200  # the drive's communication timeout these tests arm (real time)


def _powering(sims) -> bool:
    return sims.drive.state.label in ("OPERATION ENABLED", "QUICK STOP ACTIVE")


def _stopped_by_itself(sims) -> bool:
    """The simulated drive (read directly, not over the link) no longer powers the load, torque near zero."""
    return not _powering(sims) and abs(sims.physics.latest().applied_torque_nm) < 20.0


def test_connect_arms_the_drive_watchdog_and_keeps_it_fed(make_sims):
    sims = make_sims(instruments=("modbus",))  # the drive's factory setting: 1 s, fault
    sims.physics.start(speed=1.0)
    with _tcp(sims, comm_timeout_ms=WATCHDOG_MS, torque_slope_nm_per_s=20000.0) as drive:
        assert sims.drive.comm_timeout_ms == WATCHDOG_MS and sims.drive.abort_connection_option == 1
        drive.enable()
        drive.set_torque(300.0)
        # no call of the user for many timeouts: the driver's keep-alive feeds the drive
        quiet_until = time.monotonic() + 5 * WATCHDOG_MS / 1000.0
        while time.monotonic() < quiet_until:
            assert _powering(sims), sims.drive.state
            time.sleep(0.01)
        assert sims.modbus.watchdog_reactions == []
        drive.disable()
    assert sims.drive.comm_timeout_ms == 0  # closed with the drive disabled: disarmed


@pytest.mark.parametrize("option, final", [(1, "FAULT"), (3, "SWITCH ON DISABLED"), (2, "SWITCH ON DISABLED")])
def test_a_dead_master_stops_the_drive_by_itself(make_sims, option, final):
    """The master dies (no close: its keep-alive and socket just stop) with torque on: the drive reacts as its
    abort connection option says within the timeout, without any word from the master."""
    sims = make_sims(instruments=("modbus",))
    sims.physics.start(speed=1.0)
    drive = _tcp(sims, comm_timeout_ms=WATCHDOG_MS, abort_connection_option=option, torque_slope_nm_per_s=20000.0)
    drive.connect()
    drive.enable()
    drive.set_torque(-600.0)
    assert wait_until(lambda: sims.physics.latest().applied_torque_nm < -590.0)
    drive.link.stop_keepalive()  # the process is gone: nothing feeds the drive any more
    drive.link.client.close()
    assert wait_until(lambda: _stopped_by_itself(sims), timeout_s=10 * WATCHDOG_MS / 1000.0 + 2.0)
    assert sims.drive.state.label == final
    if option == 1:
        assert sims.drive.error_code == 0x8130
    assert [r["reaction"] for r in sims.modbus.watchdog_reactions] == [
        {1: "fault 0x8130", 2: "disable voltage", 3: "quick stop"}[option]]


def test_a_mute_link_stops_the_drive_by_itself(make_sims):
    sims = make_sims(instruments=("modbus",))
    sims.physics.start(speed=1.0)
    with _tcp(sims, comm_timeout_ms=WATCHDOG_MS, torque_slope_nm_per_s=20000.0) as drive:
        drive.enable()
        drive.set_torque(500.0)
        assert wait_until(lambda: sims.physics.latest().applied_torque_nm > 490.0)
        sims.inject("modbus", "mute")  # the drive hears nothing (the keep-alive's requests are lost)
        assert wait_until(lambda: _stopped_by_itself(sims), timeout_s=10 * WATCHDOG_MS / 1000.0 + 2.0)
        sims.inject("modbus", None)
        status = drive.status()
        assert status.fault and status.error_code == 0x8130


def test_watchdog_needs_its_register_or_an_explicit_off(tmp_path, drive_sims):
    packaged = Path(str(tcms_config_dir())) / "modbus-drive.toml"
    lines = [ln for ln in packaged.read_text().splitlines() if not ln.startswith("comm_timeout ")]
    without = tmp_path / "map.toml"
    without.write_text("\n".join(lines) + "\n")
    with pytest.raises(ConfigError, match="comm_timeout"):
        _tcp(drive_sims, register_map=without)
    with _tcp(drive_sims, register_map=without, comm_timeout_ms=0) as drive:  # explicitly off: runs, warned
        assert drive.status().state == "SWITCH ON DISABLED"
    with pytest.raises(ValueError, match="abort_connection_option"):
        _tcp(drive_sims, abort_connection_option=7)


def test_quick_stop_ramps_down_and_disables(drive_sims):
    with _tcp(drive_sims, torque_slope_nm_per_s=20000.0) as drive:
        drive.enable()
        drive.set_torque(400.0)
        assert wait_until(lambda: abs(drive.status().torque_actual_nm - 400.0) <= 2.0)
        drive.quick_stop()
        assert wait_until(lambda: drive.status().state == "SWITCH ON DISABLED")
        assert abs(drive.status().torque_actual_nm) <= 12.0


def test_rtu_reply_length_from_the_first_three_bytes():
    assert rtu_reply_length(bytes.fromhex("01 03 02")) == 7  # one register: id, fc, n, 2 data, CRC
    assert rtu_reply_length(bytes.fromhex("01 03 04")) == 9
    assert rtu_reply_length(bytes.fromhex("01 06 31")) == 8  # write single register: echo of the request
    assert rtu_reply_length(bytes.fromhex("01 10 31")) == 8  # write multiple registers: address + quantity
    assert rtu_reply_length(bytes.fromhex("01 83 02")) == 5  # exception: id, fc | 0x80, code, CRC
    assert rtu_reply_length(bytes.fromhex("01 2B 0E")) is None  # a function the driver never sends
    assert rtu_reply_length(b"\x01\x03") is None
    assert inter_frame_silence_s(115200, 10) == pytest.approx(1.75e-3)
    assert inter_frame_silence_s(9600, 11) == pytest.approx(3.5 * 11 / 9600)


def _serial_line(sims, port=None, **kw):
    """The driver's serial-line client (pyserial, replies by length, t3.5) on the RTU simulator."""
    return driver_for(CiA402Modbus, f"socket://127.0.0.1:{port or sims.ports['modbus_rtu']}", serial_line=True,
                        timeout_s=kw.pop("timeout_s", 0.3), **kw)


def test_serial_line_client_exchange_and_failures(drive_sims):
    sent = []
    trace = lambda sending, data: (sent.append(bytes(data)) if sending else None, data)[1]  # noqa: E731
    with _serial_line(drive_sims, trace_packet=trace, torque_slope_nm_per_s=20000.0) as drive:
        assert isinstance(drive.link.client, RtuSerialClient)
        drive.enable()
        assert bytes.fromhex("01 06 31 00 00 0F C7 32") in sent
        drive.set_torque(250.0)
        assert wait_until(lambda: abs(drive.status().torque_actual_nm - 250.0) <= 2.0)
        assert drive.link.read_register("position_actual") > 0  # a two-register reply (9 bytes)
        with pytest.raises(CommandRejected, match="exception 2"):
            drive.link.write_register("statusword", 1)  # read-only: exception reply (5 bytes)
        drive_sims.inject("modbus_rtu", "mute")
        with pytest.raises(InstrumentTimeout, match="no response"):
            drive.status()
        drive_sims.inject("modbus_rtu", None)
        drive.disable()
        assert drive.status().state == "SWITCH ON DISABLED"


def test_serial_line_client_malformed_reply(drive_sims):
    proxy = FaultProxy("127.0.0.1", drive_sims.ports["modbus_rtu"])
    port = drive_sims.loop.run(proxy.start())
    try:
        with _serial_line(drive_sims, port) as drive:
            proxy.inject("garbage")
            with pytest.raises(MalformedReply, match="do not form a valid frame"):
                drive.status()
            proxy.inject(None)
            time.sleep(0.05)
            assert drive.status().state == "SWITCH ON DISABLED"
    finally:
        drive_sims.loop.run(proxy.stop())


def test_serial_line_client_keeps_the_inter_frame_silence(drive_sims):
    """No request starts before t3.5 (1.75 ms at 115 200 Bd) after the last reply byte was read. On a manual
    timebase the driver's wait is exact and costs no real time, whatever else loads the machine."""
    timebase = ManualTime()
    with _serial_line(drive_sims, timebase=timebase) as drive:
        silence_s = drive.link.client.silence_s
        assert silence_s == pytest.approx(1.75e-3)
        port = drive.link.client.socket
        events = []
        read, write = port.read, port.write
        port.read = lambda n=1: (data := read(n), events.append(("rx", timebase.now())), data)[2]
        port.write = lambda data: (events.append(("tx", timebase.now())), write(data))[1]
        timebase.sleeps.clear()
        for _ in range(5):
            drive.link.read_register("statusword")
        gaps = [t - events[i - 1][1] for i, (kind, t) in enumerate(events) if kind == "tx" and i > 0]
        assert gaps == pytest.approx([silence_s] * 4, abs=1e-12)  # exactly t3.5: time moved only in the waits
        assert timebase.sleeps == pytest.approx([silence_s] * 5)  # the first request waits after connect's reply


def test_state_change_that_never_comes_times_out_on_the_timebase(drive_sims, monkeypatch):
    """A drive that ignores its controlword: enable() gives up after state_timeout_s of the driver's
    timebase with the state it saw — measured on a manual timebase, so the bound is exact and no real 2 s pass."""
    timebase = ManualTime()
    monkeypatch.setattr(drive_sims.drive, "write_controlword", lambda cw: None)
    with _tcp(drive_sims, timebase=timebase, state_timeout_s=2.0) as drive:
        start_s, real_start_s = timebase.now(), time.monotonic()
        with pytest.raises(InstrumentTimeout, match="did not reach READY TO SWITCH ON within 2 s.*SWITCH ON DISABLED"):
            drive.enable()
        assert 2.0 < timebase.now() - start_s <= 2.0 + 0.005 + 1e-9  # one poll interval past the deadline
        assert time.monotonic() - real_start_s < 2.0


def test_disable_waits_for_the_torque_at_most_its_ramp_time(drive_sims, monkeypatch):
    """disable() ramps the target to 0 and waits for the torque to come down, at most |torque| / slope + 0.5 s,
    then disables the voltage anyway (a drive whose torque reading sticks)."""
    timebase = ManualTime()
    with _tcp(drive_sims, timebase=timebase, torque_slope_nm_per_s=20000.0) as drive:
        drive.enable()
        drive.set_torque(400.0)
        assert wait_until(lambda: abs(drive.status().torque_actual_nm - 400.0) <= 2.0)
        stuck_permille = drive_sims.drive.torque_actual_permille()
        monkeypatch.setattr(drive_sims.drive, "torque_actual_permille", lambda: stuck_permille)
        start_s = timebase.now()
        drive.disable()
        bound_s = abs(drive.scaling.newton_metres(stuck_permille)) / 20000.0 + 0.5
        assert bound_s <= timebase.now() - start_s <= bound_s + 0.01 + 1e-9
        assert drive.status().state == "SWITCH ON DISABLED"

"""`tcms sim serve` as a separate process: an independent client that knows only the protocols (raw sockets,
plain pymodbus), and our drivers across the process boundary (ND 287, AED, CANopen via the socketcand hub,
Modbus TCP), with fault injection over the control channel."""

from __future__ import annotations

import json
import socket

import pytest
from pymodbus.client import ModbusTcpClient
from tcms_daq.drivers.aed import AED
from tcms_daq.drivers.base import DeviceFault
from tcms_daq.drivers.cia402_canopen import CiA402Canopen
from tcms_daq.drivers.cia402_modbus import CiA402Modbus
from tcms_daq.drivers.nd287 import ND287
from tcms_daq.drivers.testing import driver_for, wait_until
from tcms_daq.sim.instruments.child import running_simulators


@pytest.fixture(scope="module")
def served():
    with running_simulators("--speed", "1") as info:
        yield info


def _control(info, **request):
    with socket.create_connection(("127.0.0.1", info["ports"]["control"]), timeout=5) as sock:
        sock.sendall((json.dumps(request) + "\n").encode())
        reply = sock.makefile().readline()
    return json.loads(reply)


def _recv_until(sock: socket.socket, terminator: bytes, limit: int = 64) -> bytes:
    data = b""
    while not data.endswith(terminator) and len(data) < limit:
        chunk = sock.recv(limit - len(data))
        if not chunk:
            break
        data += chunk
    return data


def _aed_msv_nm(port: int) -> float:
    """One raw ``MSV?`` over a fresh connection, in N·m (factory NOV over a 2000 N·m nominal torque)."""
    with socket.create_connection(("127.0.0.1", port), timeout=2) as sock:
        sock.sendall(b";MSV?;")
        return int(_recv_until(sock, b"\r\n")[:8]) / 1e6 * 2000.0


def test_independent_client(served):
    ports = served["ports"]
    # ND 287: STX -> one 17-byte frame
    with socket.create_connection(("127.0.0.1", ports["nd287"]), timeout=2) as sock:
        sock.sendall(b"\x02")
        frame = _recv_until(sock, b"\r\n")
    assert len(frame) == 17 and frame[0:1] in b"+-" and frame[12:13] == b"G" and frame.endswith(b"\r\n")
    float(frame[1:11].decode().strip())
    # AED: ';' clears, MSV? -> +ddddddd CR LF
    with socket.create_connection(("127.0.0.1", ports["aed"]), timeout=2) as sock:
        sock.sendall(b";MSV?;")
        reply = _recv_until(sock, b"\r\n")
    assert len(reply) == 10 and reply[0:1] in b"+-" and reply[1:8].isdigit()
    # Modbus TCP with plain pymodbus: enable, profile torque, command and follow
    client = ModbusTcpClient("127.0.0.1", port=ports["modbus"], timeout=2)
    assert client.connect()
    try:
        for cw in (0x06, 0x07, 0x0F):
            assert not client.write_register(0x3100, cw, device_id=1).isError()
        statusword = client.read_holding_registers(0x3200, count=1, device_id=1).registers[0]
        assert statusword & 0x6F == 0x27
        assert not client.write_register(0x3500, 4, device_id=1).isError()
        assert client.read_holding_registers(0x3600, count=1, device_id=1).registers[0] == 4
        rated = client.read_holding_registers(0x3C06, count=2, device_id=1).registers
        rated_mnm = rated[0] | rated[1] << 16  # low word first
        assert rated_mnm == 2_000_000
        assert not client.write_register(0x3C00, 100, device_id=1).isError()  # 100 ‰ = 200 N·m
        def torque_actual_permille() -> int:
            return int(client.read_holding_registers(0x3C02, count=1, device_id=1).registers[0])

        assert wait_until(lambda: abs(torque_actual_permille() - 100) <= 2, timeout_s=20.0), torque_actual_permille()
        # ... and the shared physics: the AED follows to about 200 N·m (polled: the simulator's clock may lag
        # real time on a loaded machine, so no fixed delay is right)
        assert wait_until(lambda: abs(_aed_msv_nm(ports["aed"]) - 200.0) <= 5.0, timeout_s=20.0), _aed_msv_nm(ports["aed"])
        # leave the bench at rest for the next test: back to 0 N·m before disabling
        client.write_register(0x3C00, 0, device_id=1)
        assert wait_until(lambda: abs(_aed_msv_nm(ports["aed"])) <= 2.0, timeout_s=20.0), _aed_msv_nm(ports["aed"])
        client.write_register(0x3100, 0x00, device_id=1)
    finally:
        client.close()


def test_drivers_across_processes(served):
    urls = served["urls"]
    with driver_for(ND287, urls["angle"], timeout_s=1.0) as nd, driver_for(AED, urls["torque"], timeout_s=1.0) as aed, \
            driver_for(CiA402Canopen, urls["loader_canopen"], torque_slope_nm_per_s=5000.0) as drive:
        drive.enable()
        assert wait_until(lambda: abs(aed.read().value[0]) <= 2.0, timeout_s=20.0)  # at rest before the tare
        aed.tare()
        drive.set_torque(500.0)
        assert wait_until(lambda: abs(drive.status().torque_actual_nm - 500.0) <= 4.0, timeout_s=20.0)
        assert wait_until(lambda: abs(aed.read().value[0] - 500.0) <= 10.0, timeout_s=20.0), aed.read().value[0]
        assert nd.read().value[0] > 10.0  # the reducer twists towards positive angle
        assert _control(served, cmd="inject", instrument="nd287", fault="encoder_fault") == {"ok": True}
        with pytest.raises(DeviceFault):
            nd.read()
        _control(served, cmd="inject", instrument="nd287", fault=None)
        drive.disable()
    with driver_for(CiA402Modbus, urls["loader_modbus"]) as loader:
        assert loader.status().state == "SWITCH ON DISABLED"
        assert _control(served, cmd="status")["drive"]["state"] == "SWITCH ON DISABLED"


def test_control_channel_survives_an_overlong_line(served):
    """A line beyond the stream limit is answered with an error and that connection closed; the channel goes
    on serving (issue 10 item 8: it raised an uncaught LimitOverrunError)."""
    with socket.create_connection(("127.0.0.1", served["ports"]["control"]), timeout=5) as sock:
        sock.sendall(b'{"cmd": "status", "pad": "' + b"x" * 200_000 + b'"}\n')
        reply = json.loads(sock.makefile().readline())
    assert reply["ok"] is False and "longer than" in reply["error"]
    assert _control(served, cmd="status")["ok"] is True
    assert _control(served, cmd="nonsense")["error"].startswith("ValueError: unknown command")

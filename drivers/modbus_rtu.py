"""Modbus RTU on a serial line: pymodbus' serial client reading each reply by its known length.

pymodbus 3.16.1's ``ModbusSerialClient`` finds the end of a reply by polling the port until no new byte came
for one poll interval (at least 1 ms), which caps a 115 200 Bd link at about half its rate. An RTU reply's
length follows from its first three bytes (device id, function code, byte count or exception code), so
``RtuSerialClient`` reads exactly that many bytes with pyserial's blocking read (the port timeout bounds it):

    exception (function code | 0x80)    5 bytes: id, fc, code, CRC
    FC 1–4 (reads)                       5 + byte count: id, fc, n, n data bytes, CRC
    FC 5, 6, 15, 16 (writes)             8 bytes: id, fc, address, value/quantity, CRC

A reply that does not parse (bad CRC, cut short, junk) goes to pymodbus' RTU framer as read; it asks for
more, and the next read returns nothing after the port timeout: "no response" with bytes seen, which the
driver reports as a malformed reply, as before. The inter-frame silence a serial line needs is
kept by the master: no request starts before t3.5 has passed since the last byte received (3.5 characters
up to 19 200 Bd, 1.75 ms above, Modbus over serial line §2.5.1.1).
"""

from __future__ import annotations

import math

from pymodbus import FramerType
from pymodbus.client import ModbusSerialClient
from pymodbus.exceptions import ConnectionException
from tcms_daq.drivers.timebase import REAL_TIME, Timebase

RTU_HEAD_BYTES = 3
FIXED_REPLY_BYTES = {5: 8, 6: 8, 15: 8, 16: 8}


def rtu_reply_length(head: bytes) -> int | None:
    """Total length (bytes) of an RTU reply from its first three bytes; None for a function it cannot size."""
    if len(head) < RTU_HEAD_BYTES:
        return None
    function = head[1]
    if function & 0x80:
        return 5
    if function in (1, 2, 3, 4):
        return 5 + head[2]
    return FIXED_REPLY_BYTES.get(function)


def inter_frame_silence_s(baudrate: int, bits_per_char: int) -> float:
    """t3.5: 3.5 character times, fixed at 1.75 ms above 19 200 Bd."""
    return 1.75e-3 if baudrate > 19200 else 3.5 * bits_per_char / baudrate


class RtuSerialClient(ModbusSerialClient):
    """``ModbusSerialClient`` (RTU framing) that reads replies by length and keeps t3.5 before each request."""

    def __init__(self, port: str, *, baudrate: int = 19200, bytesize: int = 8, parity: str = "N",
                 stopbits: int = 1, timebase: Timebase = REAL_TIME, **kwargs):
        super().__init__(port, framer=FramerType.RTU, baudrate=baudrate, bytesize=bytesize, parity=parity,
                         stopbits=stopbits, **kwargs)
        bits_per_char = 1 + bytesize + (parity != "N") + stopbits
        self.silence_s = inter_frame_silence_s(baudrate, bits_per_char)
        self.timebase = timebase
        self._quiet_from = -math.inf  # the timebase's time from which the line has been silent for t3.5

    def send(self, request: bytes, addr: tuple | None = None) -> int:
        self.timebase.sleep(self._quiet_from - self.timebase.now())
        return super().send(request, addr)

    def recv(self, size: int | None) -> bytes:
        if size is not None:
            return super().recv(size)
        if not self.socket:
            raise ConnectionException(str(self))
        try:
            data = self.socket.read(RTU_HEAD_BYTES)
            total = rtu_reply_length(data)
            if total is not None and total > len(data):
                data += self.socket.read(total - len(data))
        except OSError:
            self.close()
            raise ConnectionException(str(self)) from None
        if data:
            self._quiet_from = self.timebase.now() + self.silence_s
        return data

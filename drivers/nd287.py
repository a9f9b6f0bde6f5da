"""Heidenhain ND 287 position display (RS-232): angle source.

Protocol (``tcms_daq.protocols.nd287``): the host sends STX (Ctrl-B, 0x02); the display latches the value at reception and
answers one 17-byte frame::

    sign  value(10 chars, leading blanks)  ' '  unit  sorting  series  CR LF
    b'-   12.3456 G  \\r\\n'   -> -12.3456 deg

Units: 'G' degrees (Grad), 'R' radians, 'M' degrees-minutes-seconds packed as ``D.MMSSs…`` (ND convention [U]:
12.3015 = 12°30'15"), '?' = fault (encoder signal error). The reading is returned in arcsec, positive in the
direction of positive torque (the display's counting direction is set up on the bench).

Serial format 7 data bits, even parity, 2 stop bits (ND 281B/287 default), baud configurable (9600 … 115 200).
The reading's time stamp is the driver clock at the moment the request byte is written (the display latches
the value when it receives STX; its delay t1 ≤ 1 ms is neglected).
"""

from __future__ import annotations

import time

import serial
from tcms_daq.drivers.base import Clock, DeviceFault, MalformedReply
from tcms_daq.drivers.options import ND287Options
from tcms_daq.drivers.timebase import REAL_TIME, Timebase
from tcms_daq.drivers.transport import SerialInstrument, open_serial_url

from tcms_daq.protocols.nd287 import FRAME_LENGTH, FRAME_RE, STX, value_to_arcsec


def parse_frame(frame: bytes, instrument: str = "ND 287") -> float:
    """Angle in arcsec from one 17-byte frame; MalformedReply for bad framing, DeviceFault for unit '?'."""
    if len(frame) != FRAME_LENGTH:
        raise MalformedReply(instrument, f"frame of {len(frame)} bytes, expected {FRAME_LENGTH}: {frame!r}")
    match = FRAME_RE.match(frame)
    if match is None:
        raise MalformedReply(instrument, f"frame does not match the ND 287 format: {frame!r}")
    sign, field, unit, _sorting, _series = match.groups()
    if unit == b"?":
        raise DeviceFault(instrument, f"display reports an encoder fault (unit '?'): {frame!r}")
    text = field.decode("ascii").strip()
    if text.count(".") > 1 or not text.replace(".", "").isdigit():
        raise MalformedReply(instrument, f"value field {field!r} is not a number: {frame!r}")
    try:
        return value_to_arcsec(float(sign.decode("ascii") + text), unit)
    except ValueError as exc:
        raise MalformedReply(instrument, f"{exc}: {frame!r}") from None


def _read_frame(port: serial.SerialBase) -> bytes:
    # size bound: a frame is 17 bytes; read a little more so an over-long garbage line is seen as such.
    return port.read_until(b"\r\n", FRAME_LENGTH + 8)


class ND287(SerialInstrument):
    """AngleSource over the ND 287 Ctrl-B protocol. ``read()`` polls ``readings_per_read`` times (arcsec)."""

    options_model = ND287Options

    def __init__(
        self,
        url: str,
        *,
        name: str = "ND 287",
        baudrate: int = 9600,
        timeout_s: float = 0.5,
        reconnect_attempts: int = 3,
        reconnect_delay_s: float = 0.2,
        readings_per_read: int = 1,
        clock: Clock = time.monotonic,
        timebase: Timebase = REAL_TIME,
        opener=open_serial_url,
    ):
        if readings_per_read < 1:
            raise ValueError(f"{name}: readings_per_read must be >= 1")
        super().__init__(url, name=name, timeout_s=timeout_s, reconnect_attempts=reconnect_attempts,
                         reconnect_delay_s=reconnect_delay_s, clock=clock, timebase=timebase, opener=opener,
                         baudrate=baudrate,
                         bytesize=serial.SEVENBITS, parity=serial.PARITY_EVEN, stopbits=serial.STOPBITS_TWO)
        self.readings_per_read = int(readings_per_read)

    def read_one(self) -> tuple[float, float]:
        """One Ctrl-B exchange -> (time_s at request, angle_arcsec)."""
        time_s = self.clock()
        return time_s, parse_frame(self.request(STX, _read_frame), self.name)

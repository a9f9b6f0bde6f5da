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

Power cycles: with an incremental encoder the display loses its datum when it loses power: it counts from the
position it was switched on at until the reference marks are traversed again, and comes back with its power-on
settings. The driver cannot restore the datum (the shaft may have moved meanwhile), so after the link was
re-opened (``ReinitialisedOnReconnect``: a link that drops and comes back is taken for a power cycle) it
re-initialises the display (DC1: output released; ENQ: its error text, logged) and counts a new datum: every
reading carries the ``angle_datum`` column (the number of power cycles the driver noticed), and the acquisition
never evaluates a loop that joins readings of two datums (``tcms_daq.analysis.gaps``).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable

import numpy as np
import serial
from tcms_daq.drivers.base import (
    Batch,
    Clock,
    CommandRejected,
    DeviceFault,
    MalformedReply,
    ReinitialisedOnReconnect,
)
from tcms_daq.drivers.options import ND287CoupledOptions, ND287Options
from tcms_daq.drivers.timebase import REAL_TIME, Timebase
from tcms_daq.drivers.transport import SerialInstrument, open_serial_url, require_terminated

from tcms_daq.analysis.gaps import ANGLE_DATUM_COLUMN
from tcms_daq.protocols.nd287 import (
    DC1,
    ENQ,
    FRAME_LENGTH,
    FRAME_RE,
    SERIES_COUPLED_DIFFERENCE,
    STX,
    value_to_arcsec,
)

log = logging.getLogger(__name__)


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


def _read_line(port: serial.SerialBase) -> bytes:
    return port.read_until(b"\r\n", 32)


class ND287(ReinitialisedOnReconnect, SerialInstrument):
    """AngleSource over the ND 287 Ctrl-B protocol. ``read()`` polls ``readings_per_read`` times (arcsec), each
    reading with its datum (``angle_datum``: power cycles noticed so far)."""

    options_model = ND287Options
    options: ND287Options

    def __init__(self, options: ND287Options, *, clock: Clock = time.monotonic, timebase: Timebase = REAL_TIME,
                 opener: Callable[..., serial.SerialBase] = open_serial_url):
        super().__init__(options, clock=clock, timebase=timebase, opener=opener,
                         bytesize=serial.SEVENBITS, parity=serial.PARITY_EVEN, stopbits=serial.STOPBITS_TWO)
        self.readings_per_read = options.readings_per_read

    def reinitialise(self) -> None:
        """Output released (DC1: a display that was told to hold answers again) and its error text read (ENQ):
        a display that reports an error after its power-up says so in the log."""
        self.link.send(DC1)
        reply = require_terminated(self.name, self.link.exchange(ENQ, _read_line))
        text = reply.strip(b"\x02\r\n").decode("ascii", errors="replace").strip()
        if text:
            log.warning("%s reports %r after (re)connecting", self.name, text)

    @property
    def datum(self) -> int:
        """The datum the readings count from: the power cycles noticed since connecting."""
        return self.power_cycles

    def read_one(self) -> tuple[float, float]:
        """One Ctrl-B exchange -> (time_s at request, angle_arcsec)."""
        time_s, reply = self.query_stamped(STX, _read_frame)
        return time_s, parse_frame(require_terminated(self.name, reply), self.name)

    def read(self) -> Batch:
        """``readings_per_read`` readings, each with the datum it counts from."""
        n = self.readings_per_read
        time_s, value, datum = np.empty(n), np.empty(n), np.empty(n)
        for i in range(n):
            time_s[i], value[i] = self.read_one()
            datum[i] = self.datum
        return Batch(time_s, value, {ANGLE_DATUM_COLUMN: datum})


class ND287Coupled(ND287):
    """The ND 287 in its coupled-axes mode (``driver = "nd287-coupled"``): inputs X1 (the output encoder) and X2 (the
    input encoder), the display showing X1 − k·X2 with k = 1/i — the transmission error at low speed, computed by the
    display from both inputs latched together, over the same RS-232 link and Ctrl-B protocol.

    What the driver does and does not do: it *reads*, it does not configure. The coupled display (X1 − X2) and the
    X2 scaling factor k are set on the display's setup menus (docs/hardware.md); the ND 287's remote commands that
    could set them are not publicly documented (protocols.md §1.3), so the driver cannot write or read k. It checks
    what it can: every frame must carry the coupled series character ``S`` (a display showing X1 or X2 alone, '1'/'2'
    or blank, is refused with CommandRejected), and it records the ratio the bench says k was set for (``ratio``).
    Assumed [U]: the display applies X2's scaling factor before coupling (X1 − SCL₂·X2), so SCL₂ = 1/i gives k = 1/i;
    confirm on the display (turn the input by a known angle at rest: the reading must not move) before a
    transmission-error test."""

    options_model = ND287CoupledOptions  # type: ignore[assignment]  # a narrower options model, as SerialInstrument's subclasses
    options: ND287CoupledOptions

    def __init__(self, options: ND287CoupledOptions, *, clock: Clock = time.monotonic,
                 timebase: Timebase = REAL_TIME, opener: Callable[..., serial.SerialBase] = open_serial_url):
        super().__init__(options, clock=clock, timebase=timebase, opener=opener)
        self.ratio = float(options.ratio)
        self.coupling_factor = 1.0 / self.ratio

    def read_one(self) -> tuple[float, float]:
        """One Ctrl-B exchange -> (time_s at request, X1 − k·X2 in arcsec); CommandRejected for a frame that is not
        the coupled display's."""
        time_s, reply = self.query_stamped(STX, _read_frame)
        frame = require_terminated(self.name, reply)
        value = parse_frame(frame, self.name)
        series = frame[14:15].decode("ascii", errors="replace")
        if series != SERIES_COUPLED_DIFFERENCE:
            raise CommandRejected(self.name, f"the display is not in its coupled mode X1 − X2 (series {series!r}, "
                                  f"expected {SERIES_COUPLED_DIFFERENCE!r}): set it on the display")
        return time_s, value

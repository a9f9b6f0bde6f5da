"""HBM AED-style torque amplifier (ASCII over RS-232/RS-485): torque source.

Command set used (protocols.md §2.2): a lone ``;`` clears the amplifier's input buffer (sent first after every
connect); ``COF3;`` selects the ASCII measured-value format; ``NOV<n>;`` sets the nominal output value (0 = the
factory scaling, 1 000 000 at nominal load); ``TAR;`` tares; ``MSV?;`` returns one measured value as
``+0012345\\r\\n`` (10 bytes). Settings are answered ``0\\r\\n`` (accepted) or ``?\\r\\n`` (rejected).

Scaling: torque_nm = value / NOV_effective × nominal_torque_nm (the sensor's nominal torque), NOV_effective =
1 000 000 when NOV = 0. A value of ±9 999 999 is the amplifier's overflow marker (sensor error or overload,
project convention [P]) and raises DeviceFault.

Serial format 8 data bits, even parity, 1 stop bit (factory 9600 Bd). After a reconnect (e.g. the amplifier was
power-cycled and came up with its power-on settings) the driver re-sends its configuration before the next
measurement: the format (``COF3``), the scaling (``NOV``) and the zero: the tare value read back (``TAV?``) after
the last ``TAR`` is written again (``TAV<±n>``), so that the readings after a restart count from the same zero.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import serial
from tcms_daq.drivers.base import (
    Clock,
    CommandRejected,
    DeviceFault,
    MalformedReply,
    ReinitialisedOnReconnect,
)
from tcms_daq.drivers.options import AEDOptions
from tcms_daq.drivers.timebase import REAL_TIME, Timebase
from tcms_daq.drivers.transport import SerialInstrument, open_serial_url, require_terminated

from tcms_daq.protocols.aed import FACTORY_NOMINAL_OUTPUT, MSV_RE, OVERFLOW_VALUE


def _read_line(port: serial.SerialBase) -> bytes:
    return port.read_until(b"\r\n", 32)


def parse_msv(reply: bytes, instrument: str = "AED") -> int:
    """The signed integer of one COF3 ``MSV?`` reply; MalformedReply / DeviceFault (overflow)."""
    if reply == b"?\r\n":
        raise CommandRejected(instrument, "amplifier rejected MSV? (measurement not available)")
    match = MSV_RE.match(reply)
    if match is None:
        raise MalformedReply(instrument, f"MSV? reply {reply!r} is not '+ddddddd\\r\\n'")
    value = int(match.group(1))
    if abs(value) >= OVERFLOW_VALUE:
        raise DeviceFault(instrument, f"amplifier reports overflow/sensor error ({value:+d})")
    return value


class AED(ReinitialisedOnReconnect, SerialInstrument):
    """TorqueSource over the AED ASCII command set. ``read()`` returns one reading (N·m) per call."""

    options_model = AEDOptions
    options: AEDOptions

    def __init__(self, options: AEDOptions, *, clock: Clock = time.monotonic, timebase: Timebase = REAL_TIME,
                 opener: Callable[..., serial.SerialBase] = open_serial_url):
        super().__init__(options, clock=clock, timebase=timebase, opener=opener,
                         bytesize=serial.EIGHTBITS, parity=serial.PARITY_EVEN, stopbits=serial.STOPBITS_ONE)
        self._tare_counts: int | None = None  # the amplifier's tare value after our last TAR (restored on restart)

    @property
    def nm_per_count(self) -> float:
        nov = self.options.nominal_output or FACTORY_NOMINAL_OUTPUT
        return self.options.nominal_torque_nm / nov

    # -- connection and configuration (re-sent after a power cycle: ReinitialisedOnReconnect) --------------

    def reinitialise(self) -> None:
        self.link.send(b";")  # clear whatever half command the amplifier holds
        self._setting(b"COF3;")
        self._setting(b"NOV%d;" % self.options.nominal_output)
        if self._tare_counts is not None:
            self._setting(b"TAV%+d;" % self._tare_counts)

    def _setting(self, command: bytes) -> None:
        reply = self.request(command, _read_line)
        if reply == b"0\r\n":
            return
        if reply == b"?\r\n":
            raise CommandRejected(self.name, f"amplifier rejected {command.decode('ascii')!r}")
        raise MalformedReply(self.name, f"reply {reply!r} to {command.decode('ascii')!r} is neither '0' nor '?'")

    # -- TorqueSource ------------------------------------------------------------------------------------

    def read_one(self) -> tuple[float, float]:
        """One ``MSV?;`` exchange -> (time_s at request, torque_nm)."""
        time_s, reply = self.query_stamped(b"MSV?;", _read_line)
        return time_s, parse_msv(require_terminated(self.name, reply), self.name) * self.nm_per_count

    def tare(self) -> None:
        """Zero the amplifier at the present load and keep its tare value, to restore it after a restart."""
        self.ensure_configured()
        self._setting(b"TAR;")
        reply = require_terminated(self.name, self.query_stamped(b"TAV?;", _read_line)[1])
        try:
            self._tare_counts = int(reply.strip())
        except ValueError:
            raise MalformedReply(self.name, f"TAV? reply {reply!r} is not a signed integer") from None

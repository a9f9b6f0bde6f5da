"""A serial link for request/reply ASCII instruments (ND 287, AED) with timeouts and a bounded reconnect.

One code path for hardware and simulators: the link opens any pyserial URL (``/dev/ttyUSB0``,
``socket://127.0.0.1:4001``, ``rfc2217://…``, ``spy://…``) with every serial setting passed to the constructor
(Linux ptys silently drop parity/7-bit settings on a later reconfiguration, see protocols.md §5.4).

Failure mapping (one exception type per failure, the instrument always named):
- no byte within the timeout                     -> InstrumentTimeout
- some bytes, but not a complete reply            -> MalformedReply (the caller validates complete replies too)
- the link is gone and ``reconnect_attempts`` re-opens did not bring it back -> Disconnected

``SerialInstrument`` is the driver shell both ASCII instruments share: one link, connect/close, a polled
``read()`` that returns a Batch of ``read_one()`` readings stamped at the request.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Self, TypeVar

import numpy as np
import serial
from tcms_daq.drivers.base import Batch, Clock, Disconnected, InstrumentTimeout, MalformedReply
from tcms_daq.drivers.options import SerialOptions
from tcms_daq.drivers.timebase import REAL_TIME, Timebase

# A function that reads one reply from an open port (e.g. ``lambda port: port.read_until(b"\r\n", 64)``).
ReplyReader = Callable[[serial.SerialBase], bytes]
T = TypeVar("T")


def open_serial_url(url: str, **settings: Any) -> serial.SerialBase:
    """``serial.serial_for_url`` with all settings in the constructor (never reconfigured afterwards)."""
    return serial.serial_for_url(url, **settings)


class SerialLink:
    """A request/reply link: ``exchange(request, reader)`` writes ``request`` and returns the reply bytes.

    The link re-opens the port when it finds it closed or broken (peer closed the socket, USB unplugged) at most
    ``reconnect_attempts`` times, ``reconnect_delay_s`` apart, and then retries the request once. A timeout is
    not a broken link: it raises at once and the next exchange starts from a drained input buffer.
    """

    def __init__(
        self,
        instrument: str,
        url: str,
        *,
        timeout_s: float,
        reconnect_attempts: int = 3,
        reconnect_delay_s: float = 0.2,
        opener: Callable[..., serial.SerialBase] = open_serial_url,
        timebase: Timebase = REAL_TIME,
        **serial_settings: Any,
    ):
        if timeout_s <= 0:
            raise ValueError(f"{instrument}: timeout_s must be > 0, got {timeout_s}")
        self.instrument = instrument
        self.url = url
        self.timeout_s = float(timeout_s)
        self.reconnect_attempts = int(reconnect_attempts)
        self.reconnect_delay_s = float(reconnect_delay_s)
        self._opener = opener
        self.timebase = timebase
        self._settings = dict(serial_settings, timeout=self.timeout_s, write_timeout=self.timeout_s)
        self._port: serial.SerialBase | None = None
        self.reconnects = 0  # successful re-opens after a broken link (for diagnostics)

    @property
    def is_open(self) -> bool:
        return self._port is not None and self._port.is_open

    def open(self) -> None:
        """Open the port (one attempt); raises Disconnected if it cannot be opened."""
        if self.is_open:
            return
        try:
            self._port = self._opener(self.url, **self._settings)
        except (serial.SerialException, OSError, ValueError) as exc:
            self._port = None
            raise Disconnected(self.instrument, f"cannot open {self.url}: {exc}") from exc

    def close(self) -> None:
        port, self._port = self._port, None
        if port is not None:
            try:
                port.close()
            except (serial.SerialException, OSError):
                pass

    def _reopen(self, reason: BaseException | str) -> None:
        self.close()
        last: BaseException | str = reason
        for attempt in range(self.reconnect_attempts):
            if attempt:
                self.timebase.sleep(self.reconnect_delay_s)
            try:
                self.open()
                self.reconnects += 1
                return
            except Disconnected as exc:
                last = exc.__cause__ or exc
        raise Disconnected(
            self.instrument,
            f"link to {self.url} lost ({reason}); {self.reconnect_attempts} reconnect attempts failed: {last}",
        )

    def exchange(self, request: bytes, reader: ReplyReader) -> bytes:
        """Send ``request`` and return the raw reply; empty reply -> InstrumentTimeout."""
        reply = self._once_more(lambda: self._exchange_once(request, reader))
        if not reply:
            raise InstrumentTimeout(
                self.instrument, f"no reply to {request!r} within {self.timeout_s:g} s on {self.url}"
            )
        return reply

    def send(self, request: bytes) -> None:
        """Write without expecting a reply (e.g. the AED buffer-clearing ';')."""
        self._once_more(lambda: self._write(request))

    def _once_more(self, op: Callable[[], T]) -> T:
        """Run ``op`` on an open port; on a broken link (e.g. the simulator restarted) re-open, then retry
        exactly once."""
        if not self.is_open:
            self._reopen("port not open")
        try:
            return op()
        except (serial.SerialException, OSError) as exc:
            self._reopen(exc)
            try:
                return op()
            except (serial.SerialException, OSError) as exc2:
                self.close()
                raise Disconnected(self.instrument, f"link to {self.url} broken again: {exc2}") from exc2

    def _write(self, request: bytes) -> None:
        port = self._port
        assert port is not None
        port.write(request)
        port.flush()

    def _exchange_once(self, request: bytes, reader: ReplyReader) -> bytes:
        port = self._port
        assert port is not None
        port.reset_input_buffer()  # drop late bytes of an earlier timed-out or malformed reply
        self._write(request)
        return reader(port)


def require_terminated(instrument: str, reply: bytes, terminator: bytes = b"\r\n") -> bytes:
    """MalformedReply if ``reply`` (non-empty) lacks its terminator: a partial frame cut off by the timeout."""
    if not reply.endswith(terminator):
        raise MalformedReply(instrument, f"incomplete reply {reply!r} (no {terminator!r} before the timeout)")
    return reply


class SerialInstrument:
    """A polled request/reply instrument on one ``SerialLink``; subclasses define ``read_one()``.

    The options' baudrate and the subclass's ``framing`` (bytesize, parity, stopbits) go to the port's
    constructor; software flow control is always off (the replies are binary-clean ASCII frames, XON/XOFF would eat bytes).
    """

    readings_per_read = 1

    def __init__(
        self,
        options: SerialOptions,
        *,
        clock: Clock,
        opener: Callable[..., serial.SerialBase],
        timebase: Timebase = REAL_TIME,
        **framing: Any,
    ):
        self.options = options
        self.name = options.name
        self.clock = clock
        self.link = SerialLink(options.name, options.url, timeout_s=options.timeout_s,
                               reconnect_attempts=options.reconnect_attempts,
                               reconnect_delay_s=options.reconnect_delay_s, opener=opener, timebase=timebase,
                               xonxoff=False, baudrate=options.baudrate, **framing)

    def connect(self) -> None:
        self.link.open()

    def close(self) -> None:
        self.link.close()

    def request(self, command: bytes, reader: ReplyReader, terminator: bytes = b"\r\n") -> bytes:
        """One exchange; the reply is complete (ends with ``terminator``) or MalformedReply."""
        return require_terminated(self.name, self.link.exchange(command, reader), terminator)

    def read_one(self) -> tuple[float, float]:
        """One reading: (time_s at the request, value in the channel's unit)."""
        raise NotImplementedError

    def read(self) -> Batch:
        """``readings_per_read`` polled readings."""
        n = self.readings_per_read
        time_s, value = np.empty(n), np.empty(n)
        for i in range(n):
            time_s[i], value[i] = self.read_one()
        return Batch(time_s, value)

    def __enter__(self) -> Self:
        self.connect()
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

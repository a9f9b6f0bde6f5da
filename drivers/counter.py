"""The two-axis counter interface (``driver = "counter-2axis"``): both encoders latched as one pair at kHz.

Protocol ``tcms_daq.protocols.counter`` [P]. ``connect()`` checks the card (IDN?), its counts per revolution against
the options (CONF?: a card set up for other encoders is refused), sets the latch rate, zeroes nothing (the datum is
the card's) and starts latching. ``read()`` drains the FIFO (READ, repeated while a block comes back full): a Batch
with the output angle (axis 1, arcsec) in ``value`` and the input angle (axis 2, arcsec of the input shaft) in
``extra["input_angle_arcsec"]``, the card's sequence number in ``extra["latch_seq"]``. An overflowed FIFO (frames
lost) and a signal fault of either axis raise DeviceFault; a broken block MalformedReply.

Time stamps: each frame carries the latch time on the card's clock (µs). The driver maps it onto its own clock by
the offset of its quickest recent read when the two clocks run at one rate (the newest latch taken between request
and reply: their middle, as NTP), slewed so that the times never step, else (a simulator at another speed than the driver's clock) by the line through the
first and the latest (request time, newest latch time) pair.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np
import serial
from tcms_daq.drivers.base import (
    INPUT_ANGLE_COLUMN,
    Batch,
    Clock,
    CommandRejected,
    DeviceFault,
    MalformedReply,
)
from tcms_daq.drivers.options import CounterOptions
from tcms_daq.drivers.timebase import REAL_TIME, Timebase
from tcms_daq.drivers.transport import SerialInstrument, open_serial_url, require_terminated

from tcms_daq.protocols.counter import (
    ARCSEC_PER_REV,
    CRC,
    FLAG_OVERFLOW,
    HEADER,
    MAX_FRAMES_PER_READ,
    STATUS_AXIS1_FAULT,
    STATUS_AXIS2_FAULT,
    block_length,
    decode_block,
    parse_conf,
)

LATCH_SEQ_COLUMN = "latch_seq"
MIN_DRIFT_SPAN_S = 1.0  # the clock line's slope is estimated once the card's times span this much
SAME_RATE = 0.05  # clocks whose rates differ less than this share run at one rate (offset only)
OFFSET_WINDOW_S = 10.0  # the offset's target: the quickest read of this long (a drifting card is followed)
OFFSET_SLEW = 0.01  # the offset in use moves toward its target at most this many s per s


def _read_line(port: serial.SerialBase) -> bytes:
    return port.read_until(b"\r\n", 128)


def _read_block(port: serial.SerialBase) -> bytes:
    header = port.read(HEADER.size)
    if len(header) < HEADER.size:
        return header
    try:
        length = block_length(header)
    except ValueError:
        return header + port.read(CRC.size)
    return header + port.read(length - HEADER.size)


class Counter2Axis(SerialInstrument):
    """AngleSource with the input angle beside the output angle, latched as pairs."""

    options_model = CounterOptions
    options: CounterOptions

    def __init__(self, options: CounterOptions, *, clock: Clock = time.monotonic, timebase: Timebase = REAL_TIME,
                 opener: Callable[..., serial.SerialBase] = open_serial_url):
        super().__init__(options, clock=clock, timebase=timebase, opener=opener, bytesize=serial.EIGHTBITS,
                         parity=serial.PARITY_NONE, stopbits=serial.STOPBITS_ONE)
        self._first: tuple[float, float] | None = None  # (host s, card s) of the first read with frames
        self._latest: tuple[float, float] | None = None
        self._offset: float | None = None  # host − card in use (s)
        self._target: float | None = None  # host − card of the quickest recent read (s)
        self._round_trip = float("inf")  # that read's round trip (s)
        self._target_at = self._updated_at = 0.0

    def _command(self, line: str) -> str:
        reply = require_terminated(self.name, self.link.exchange(line.encode("ascii") + b"\n", _read_line))
        text = reply.decode("ascii", errors="replace").strip()
        if text.startswith("ERR"):
            raise CommandRejected(self.name, f"{line}: {text}")
        return text

    def connect(self) -> None:
        super().connect()
        idn = self._command("IDN?")
        if not idn.startswith("TCMS-2AX"):
            raise MalformedReply(self.name, f"IDN? answered {idn!r}, not a two-axis counter")
        self._command("STOP")
        try:
            conf = parse_conf(self._command("CONF?"))
        except ValueError as exc:
            raise MalformedReply(self.name, str(exc)) from None
        options = self.options
        for key, want in (("CPR1", options.counts_per_rev_output), ("CPR2", options.counts_per_rev_input)):
            if conf[key] != want:
                raise CommandRejected(self.name, f"the card counts {conf[key]} per revolution on {key}, the bench "
                                      f"config says {want}")
        self._command(f"RATE {options.rate_hz}")
        self._command("START")
        self._first = self._latest = None
        self._offset = self._target = None
        self._round_trip = float("inf")

    def close(self) -> None:
        try:
            if self.link.is_open:
                self._command("STOP")
        except Exception:  # noqa: BLE001 - closing anyway
            pass
        super().close()

    def _track_offset(self, request_s: float, reply_s: float, newest_card_s: float) -> None:
        """The newest latch was taken while the READ was on the way: host − card ≈ the middle of request and reply
        − the newest latch (error at most half the round trip, as NTP's). The target is the quickest read's of the
        last ``OFFSET_WINDOW_S`` (a drifting card is followed); the offset in use slews toward it at most
        ``OFFSET_SLEW`` s per s, so the mapped times never step (a step would be a gap, or a jump back, in the record)."""
        estimate, round_trip = 0.5 * (request_s + reply_s) - newest_card_s, reply_s - request_s
        if (self._target is None or round_trip <= self._round_trip
                or request_s - self._target_at > OFFSET_WINDOW_S):
            self._target, self._round_trip, self._target_at = estimate, round_trip, request_s
        if self._offset is None:
            self._offset = self._target
        else:
            limit = OFFSET_SLEW * max(0.0, request_s - self._updated_at)
            self._offset += max(-limit, min(limit, self._target - self._offset))
        self._updated_at = request_s

    def _card_to_clock(self, card_s: np.ndarray) -> np.ndarray:
        """The card's latch times on the driver's clock. When the two clocks run at one rate (within
        ``SAME_RATE``: a crystal's drift is tens of ppm, a few ms over a minute's test; the bench's clock runs at a
        simulator's speed), by the offset :meth:`_track_offset` keeps (no step: the record stays continuous).
        Otherwise (another rate, once the card's times span ``MIN_DRIFT_SPAN_S``) by the line through the first and
        the latest (request time, newest latch) pair."""
        first, latest = self._first, self._latest
        if first is None or latest is None:
            return card_s
        span = latest[1] - first[1]
        scale = (latest[0] - first[0]) / span if span >= MIN_DRIFT_SPAN_S else 1.0
        if abs(scale - 1.0) > SAME_RATE:
            return first[0] + (card_s - first[1]) * scale
        assert self._offset is not None
        return card_s + self._offset

    def read(self) -> Batch:
        frames: list[tuple[int, int, int, int, int]] = []
        while True:
            request_s = self.clock()
            block = self.link.exchange(b"READ\n", _read_block)
            try:
                part, flags, lost = decode_block(block)
            except ValueError as exc:
                raise MalformedReply(self.name, f"READ: {exc}") from None
            if flags & FLAG_OVERFLOW:
                raise DeviceFault(self.name, f"FIFO overflow: {lost} latched pairs lost (read more often)")
            frames += part
            if part:
                reply_s = self.clock()
                pair = (request_s, part[-1][1] / 1e6)
                if self._first is None:
                    self._first = pair
                self._latest = pair
                self._track_offset(request_s, reply_s, pair[1])
            if len(part) < MAX_FRAMES_PER_READ:
                break
        if not frames:
            return Batch.empty()
        data = np.asarray(frames, dtype=np.int64)
        status = np.bitwise_or.reduce(data[:, 4])
        if status & (STATUS_AXIS1_FAULT | STATUS_AXIS2_FAULT):
            axes = [n for bit, n in ((STATUS_AXIS1_FAULT, "1 (output)"), (STATUS_AXIS2_FAULT, "2 (input)"))
                    if status & bit]
            raise DeviceFault(self.name, f"encoder signal fault on axis {', '.join(axes)}")
        options = self.options
        time_s = self._card_to_clock(data[:, 1] / 1e6)
        output = data[:, 2] / options.counts_per_rev_output * ARCSEC_PER_REV
        input_ = data[:, 3] / options.counts_per_rev_input * ARCSEC_PER_REV
        return Batch(time_s, output, {INPUT_ANGLE_COLUMN: input_, LATCH_SEQ_COLUMN: data[:, 0].astype(float)})

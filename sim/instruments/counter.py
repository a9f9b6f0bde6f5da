"""The two-axis counter interface simulator (protocol: ``tcms_daq.protocols.counter``): latches the output and the
input encoder's counts together at RATE on the simulated clock, into a FIFO the host drains with READ.

Counts: axis 1 = the output encoder (``output_angle_arcsec(times)``: the bench's encoder reading plus the rotation the
drivetrain gives), axis 2 = the input encoder (``input_angle_deg(times)``), each on its counts per revolution; both
readers take an array of times and give an array. Latching is lazy: a READ (or CONF?/STOP) first latches every
trigger time up to the simulated clock's now, each at its own time (the drivetrain is asked for exact angles at
those times), so the pairs are as a real card's timer would give them. Faults: the common ones (mute, garbage, partial) and ``signal_fault`` (status bits of both axes set).
"""

from __future__ import annotations

import asyncio
import collections
import math
from collections.abc import Callable

import numpy as np
from tcms_daq.sim.instruments.tcp import TcpInstrumentServer

from tcms_daq.protocols.counter import (
    ARCSEC_PER_REV,
    FLAG_OVERFLOW,
    FLAG_STOPPED,
    MAX_FRAMES_PER_READ,
    MAX_RATE_HZ,
    MIN_RATE_HZ,
    STATUS_AXIS1_FAULT,
    STATUS_AXIS2_FAULT,
    Frame,
    encode_block,
)

GARBAGE_BLOCK = b"2AXB\x05\x00\x00\x00junk"


class CounterServer(TcpInstrumentServer):
    name = "two-axis counter sim"
    DEVICE_FAULTS = ("signal_fault",)

    def __init__(self, now_s: Callable[[], float], output_angle_arcsec: Callable[[np.ndarray], np.ndarray],
                 input_angle_deg: Callable[[np.ndarray], np.ndarray], *, counts_per_rev_1: int = 18_000 * 4096,
                 counts_per_rev_2: int = 1 << 23, rate_hz: int = 1000, fifo_frames: int = 8192,
                 host: str = "127.0.0.1", port: int = 0, reply_delay_s: float = 0.0):
        super().__init__(host, port, reply_delay_s)
        self.now_s = now_s
        self.output_angle_arcsec = output_angle_arcsec
        self.input_angle_deg = input_angle_deg
        self.cpr1, self.cpr2 = int(counts_per_rev_1), int(counts_per_rev_2)
        self.rate_hz = int(rate_hz)
        self.fifo: collections.deque[Frame] = collections.deque(maxlen=int(fifo_frames))
        self.running_latch = False
        self.sequence = 0
        self._next_latch_s = 0.0
        self._offset1 = self._offset2 = 0  # ZERO: the counts at the datum
        self._lost = 0

    def _latch_until_now(self) -> None:
        if not self.running_latch:
            return
        now = self.now_s()
        period = 1.0 / self.rate_hz
        status = (STATUS_AXIS1_FAULT | STATUS_AXIS2_FAULT) if self.fault == "signal_fault" else 0
        n = int(math.floor((now - self._next_latch_s) / period + 1e-9)) + 1 if self._next_latch_s <= now else 0
        if n <= 0:
            return
        times = self._next_latch_s + period * np.arange(n)
        # the angles of every trigger time at once (a vectorised reader: the turning unit's drivetrain)
        out = np.asarray(self.output_angle_arcsec(times), dtype=float)
        inp = np.asarray(self.input_angle_deg(times), dtype=float)
        counts1 = np.round(out / ARCSEC_PER_REV * self.cpr1).astype(np.int64) - self._offset1
        counts2 = np.round(inp / 360.0 * self.cpr2).astype(np.int64) - self._offset2
        for t, count1, count2 in zip(times.tolist(), counts1.tolist(), counts2.tolist(), strict=True):
            if len(self.fifo) == self.fifo.maxlen:
                self._lost += 1
            self.fifo.append((self.sequence & 0xFFFFFFFF, round(t * 1e6), count1, count2, status))
            self.sequence += 1
        self._next_latch_s = float(times[-1]) + period

    def command(self, line: str) -> bytes:
        words = line.strip().upper().split()
        if not words:
            return b""
        cmd, args = words[0], words[1:]
        if cmd == "IDN?":
            return b"TCMS-2AX,1.0\r\n"
        if cmd == "CONF?":
            return f"RATE={self.rate_hz} CPR1={self.cpr1} CPR2={self.cpr2} FIFO={self.fifo.maxlen}\r\n".encode()
        if cmd == "RATE" and len(args) == 1:
            if self.running_latch:
                return b"ERR latching: STOP first\r\n"
            try:
                rate = int(args[0])
            except ValueError:
                return b"ERR not a number\r\n"
            if not MIN_RATE_HZ <= rate <= MAX_RATE_HZ:
                return f"ERR rate {rate} out of {MIN_RATE_HZ}..{MAX_RATE_HZ} Hz\r\n".encode()
            self.rate_hz = rate
            return b"OK\r\n"
        if cmd == "START":
            self.fifo.clear()
            self._lost = 0
            self.running_latch = True
            self._next_latch_s = self.now_s()
            return b"OK\r\n"
        if cmd == "STOP":
            self._latch_until_now()
            self.running_latch = False
            return b"OK\r\n"
        if cmd == "ZERO":
            now = self.now_s()
            at = np.array([now])
            self._offset1 = round(float(np.asarray(self.output_angle_arcsec(at))[0]) / ARCSEC_PER_REV * self.cpr1)
            self._offset2 = round(float(np.asarray(self.input_angle_deg(at))[0]) / 360.0 * self.cpr2)
            return b"OK\r\n"
        if cmd == "READ":
            self._latch_until_now()
            frames = [self.fifo.popleft() for _ in range(min(len(self.fifo), MAX_FRAMES_PER_READ))]
            flags = (FLAG_OVERFLOW if self._lost else 0) | (0 if self.running_latch else FLAG_STOPPED)
            block = encode_block(frames, flags=flags, lost=self._lost)
            self._lost = 0
            return block
        return b"ERR unknown command\r\n"

    async def serve_connection(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        while True:
            line = await reader.readline()
            if not line:
                return
            reply = self.command(line.decode("ascii", errors="replace"))
            if reply:
                await self.reply(writer, reply, GARBAGE_BLOCK)

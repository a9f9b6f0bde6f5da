"""The two-axis counter interface's wire protocol [P: this project's own, modelled on what encoder counter cards do:
the HEIDENHAIN EIB 74x latches all axes on one trigger from its own timer into a FIFO with a time stamp, the host
drains it; that card's protocol is not public, so the simulator and the driver speak this one].

Link: TCP (``socket://host:port`` for the driver) or a serial line. Commands are ASCII lines ending in LF; each is
answered by one line ending in CR LF, except ``READ``:

    IDN?          -> ``TCMS-2AX,<firmware>``
    CONF?         -> ``RATE=<Hz> CPR1=<counts> CPR2=<counts> FIFO=<frames>``  (CPR: counts per revolution)
    RATE <Hz>     -> ``OK`` | ``ERR <text>``   latch rate of the card's timer (1 … 20 000 Hz; while stopped)
    START         -> ``OK``   clear the FIFO, latch both counters together at RATE from now on
    STOP          -> ``OK``   stop latching (the FIFO keeps what it has)
    ZERO          -> ``OK``   both counters to 0 (the datum of both axes)
    READ          -> a binary block: the oldest frames of the FIFO (at most ``MAX_FRAMES_PER_READ``)

Block: header ``<4sHHI`` = magic ``b"2AXB"``, frame count n (u16), flags (u16: bit 0 the FIFO overflowed since the
last READ, bit 1 latching is stopped), frames lost to overflows since the last READ (u32); n frames ``<IQqqI`` (32
bytes): sequence number (u32, counts every latch), latch time (u64 µs on the card's clock), axis 1 count (i64: the
output encoder), axis 2 count (i64: the input encoder), status (u32: bit 0 axis 1 signal fault, bit 1 axis 2 signal
fault); then the CRC-32 (zlib) of header and frames (u32). All little-endian. Both counts of a frame were latched by
the same trigger: they are one pair, whatever the link's latency.
"""

from __future__ import annotations

import struct
import zlib

MAGIC = b"2AXB"
HEADER = struct.Struct("<4sHHI")
FRAME = struct.Struct("<IQqqI")
CRC = struct.Struct("<I")
MAX_FRAMES_PER_READ = 1024
FLAG_OVERFLOW = 0x1
FLAG_STOPPED = 0x2
STATUS_AXIS1_FAULT = 0x1
STATUS_AXIS2_FAULT = 0x2
MIN_RATE_HZ, MAX_RATE_HZ = 1, 20_000
ARCSEC_PER_REV = 1_296_000.0

Frame = tuple[int, int, int, int, int]  # sequence, time µs, count 1, count 2, status


def encode_block(frames: list[Frame], *, flags: int = 0, lost: int = 0) -> bytes:
    body = HEADER.pack(MAGIC, len(frames), flags, lost) + b"".join(FRAME.pack(*f) for f in frames)
    return body + CRC.pack(zlib.crc32(body))


def block_length(header: bytes) -> int:
    """The whole block's length from its header (ValueError for a header that is not one)."""
    magic, count, _flags, _lost = HEADER.unpack(header)
    if magic != MAGIC:
        raise ValueError(f"not a READ block: magic {magic!r}")
    return HEADER.size + int(count) * FRAME.size + CRC.size


def decode_block(block: bytes) -> tuple[list[Frame], int, int]:
    """(frames, flags, lost) of a whole block; ValueError for a wrong magic, length or CRC."""
    if len(block) < HEADER.size + CRC.size:
        raise ValueError(f"block of {len(block)} bytes is shorter than a header")
    magic, count, flags, lost = HEADER.unpack_from(block)
    if magic != MAGIC:
        raise ValueError(f"not a READ block: magic {magic!r}")
    expected = HEADER.size + count * FRAME.size + CRC.size
    if len(block) != expected:
        raise ValueError(f"block of {len(block)} bytes, expected {expected} for {count} frames")
    (crc,) = CRC.unpack_from(block, expected - CRC.size)
    if crc != zlib.crc32(block[: expected - CRC.size]):
        raise ValueError("block CRC mismatch")
    frames = [FRAME.unpack_from(block, HEADER.size + i * FRAME.size) for i in range(count)]
    return frames, flags, lost


def parse_conf(line: str) -> dict[str, int]:
    """``RATE=1000 CPR1=… CPR2=… FIFO=…`` -> {"RATE": 1000, …}; ValueError when a field is missing or not a number."""
    fields = dict(part.split("=", 1) for part in line.split() if "=" in part)
    try:
        return {key: int(fields[key]) for key in ("RATE", "CPR1", "CPR2", "FIFO")}
    except (KeyError, ValueError) as exc:
        raise ValueError(f"CONF? reply {line!r}: {exc}") from None

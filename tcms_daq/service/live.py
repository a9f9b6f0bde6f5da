"""Live telemetry hub: acquisition batches → 20–30 binary frames/s → every WebSocket client.

The acquisition thread calls :meth:`LiveHub.publish` with column batches (no awaiting, no I/O). A framer task on
the event loop collects what arrived since the last tick, encodes ONE frame and offers the same bytes to each
client's bounded queue. Every client has its own sender task, so a slow client only ever waits on itself: when
its queue is full the oldest frame is dropped and counted, and a send that stays blocked longer than
``stall_timeout_s`` evicts the client. There is no loop that awaits the clients one after the other.

Binary frame (little-endian), see :data:`FRAME_HEADER`::

    magic  4s  b"TCMS"
    version u16 (1)
    n_channels u16
    sequence u64   per-stream frame number, +1 per frame, starts at 1
    t0_s f64       time stamp of the first sample in the frame (s, acquisition clock)
    n_samples u32
    dropped u32    frames this client has lost so far (cumulative)
    then n_channels float32 columns of n_samples each, in schema order;
    the time column holds time_s − t0_s (s).

Decimation: a frame holds at most ``max_samples_per_frame`` samples (default 4000: 100 kS/s at 25 frames/s
pass untouched). Above that, the frame's samples are cut into equal buckets and each bucket keeps the samples
holding its minimum and maximum torque and compensated angle — whole samples in time order, so the time traces
keep their envelope and every (torque, angle) point of the live loop is a real measured pair. Stored samples
and exports are never decimated.
"""

from __future__ import annotations

import asyncio
import struct
import threading
import time
from collections import deque
from collections.abc import Awaitable, Callable, Mapping
from dataclasses import dataclass

import numpy as np

from tcms_daq.service.clients import ClientQueue, WhenFull
from tcms_daq.service.events import run_until_either

FRAME_MAGIC = b"TCMS"
FRAME_VERSION = 1
FRAME_HEADER = struct.Struct("<4sHHQdII")
_DROPPED_OFFSET = FRAME_HEADER.size - 4

# (name, unit, description) in frame column order
LIVE_CHANNELS: tuple[tuple[str, str, str], ...] = (
    ("time_s", "s", "sample time stamp minus the frame's t0_s"),
    ("torque_nm", "N·m", "measured torque"),
    ("encoder_arcsec", "arcsec", "raw encoder angle"),
    ("angle_arcsec", "arcsec", "compensated angle"),
)


def schema_message(frame_rate_hz: float, max_samples_per_frame: int | None = None) -> dict:
    """The JSON text message sent to a client before any binary frame."""
    return {
        "type": "schema",
        "version": FRAME_VERSION,
        "byte_order": "little",
        "header": {
            "format": FRAME_HEADER.format,
            "size": FRAME_HEADER.size,
            "fields": ["magic", "version", "n_channels", "sequence", "t0_s", "n_samples", "dropped"],
        },
        "dtype": "float32",
        "layout": "channel-major",
        "frame_rate_hz": frame_rate_hz,
        "max_samples_per_frame": max_samples_per_frame,
        "decimation": "per bucket the samples with min and max torque_nm and angle_arcsec (whole samples, time "
                      "order) when a frame would hold more than max_samples_per_frame",
        "channels": [{"name": n, "unit": u, "description": d} for n, u, d in LIVE_CHANNELS],
    }


DECIMATION_KEYS: tuple[str, ...] = ("torque_nm", "angle_arcsec")


def minmax_rows(columns: Mapping[str, np.ndarray], max_samples: int) -> np.ndarray | None:
    """Row indices (ascending) of a min/max decimation to at most ``max_samples`` rows, or None when the
    columns already fit. Each bucket contributes the rows of its min and max of every :data:`DECIMATION_KEYS`
    channel (fewer when they coincide)."""
    n = len(columns["time_s"])
    per_bucket = 2 * len(DECIMATION_KEYS)
    if n <= max_samples or max_samples < per_bucket:
        return None
    size = -(-n // (max_samples // per_bucket))  # samples per bucket (ceil)
    buckets = -(-n // size)  # the last bucket may be short: it is padded with its own last sample
    pad = buckets * size - n
    picks = []
    for key in DECIMATION_KEYS:
        values = np.asarray(columns[key], dtype=float)
        grid = np.pad(values, (0, pad), mode="edge").reshape(buckets, size)
        start = np.arange(buckets) * size
        picks += [start + grid.argmin(axis=1), start + grid.argmax(axis=1)]
    return np.unique(np.minimum(np.concatenate(picks), n - 1))


def encode_frame(sequence: int, columns: Mapping[str, np.ndarray], dropped: int = 0) -> bytes:
    """Encode one frame from float columns keyed by the names in :data:`LIVE_CHANNELS`."""
    time_s = np.asarray(columns["time_s"], dtype=np.float64)
    n = len(time_s)
    t0 = float(time_s[0]) if n else 0.0
    block = np.empty((len(LIVE_CHANNELS), n), dtype="<f4")
    block[0] = time_s - t0
    for i, (name, _, _) in enumerate(LIVE_CHANNELS[1:], start=1):
        block[i] = columns[name]
    header = FRAME_HEADER.pack(FRAME_MAGIC, FRAME_VERSION, len(LIVE_CHANNELS), sequence, t0, n, dropped)
    return header + block.tobytes()


@dataclass(frozen=True)
class DecodedFrame:
    sequence: int
    t0_s: float
    dropped: int
    columns: dict[str, np.ndarray]  # time_s is absolute again (t0_s added back, float64)

    @property
    def n_samples(self) -> int:
        return len(self.columns["time_s"])


def decode_frame(data: bytes) -> DecodedFrame:
    """Inverse of :func:`encode_frame` (used by tests, benchmarks and Python clients)."""
    magic, version, n_channels, seq, t0, n, dropped = FRAME_HEADER.unpack_from(data)
    if magic != FRAME_MAGIC or version != FRAME_VERSION:
        raise ValueError(f"not a TCMS live frame (magic {magic!r}, version {version})")
    expected = FRAME_HEADER.size + 4 * n_channels * n
    if len(data) != expected:
        raise ValueError(f"frame has {len(data)} bytes, header says {expected}")
    block = np.frombuffer(data, dtype="<f4", offset=FRAME_HEADER.size).reshape(n_channels, n)
    cols = {name: block[i].astype(np.float64) for i, (name, _, _) in enumerate(LIVE_CHANNELS[:n_channels])}
    cols["time_s"] = cols["time_s"] + t0
    return DecodedFrame(seq, t0, dropped, cols)


def with_dropped(frame: bytes, dropped: int) -> bytes:
    """The same frame with the per-client dropped counter patched into the header (one copy, no re-encode)."""
    return frame[:_DROPPED_OFFSET] + struct.pack("<I", min(dropped, 0xFFFFFFFF)) + frame[FRAME_HEADER.size :]


class LiveClient(ClientQueue[bytes]):
    """A live client: bounded frame queue that drops its oldest frame when full (the count is patched into the
    header of each frame it is sent), evicted when one send blocks longer than ``stall_timeout_s``."""

    def __init__(self, send: Callable[[bytes], Awaitable[None]], *, name: str, max_queue: int = 50,
                 stall_timeout_s: float = 5.0):
        super().__init__(send, max_queue=max_queue, when_full=WhenFull.DROP_OLDEST, name=name,
                         stall_timeout_s=stall_timeout_s)

    async def run(self, prepare: Callable[[bytes], bytes | None] | None = None) -> None:
        await super().run(prepare or (lambda frame: with_dropped(frame, self.dropped) if self.dropped else frame))


class LiveHub:
    """Collects batches from the acquisition thread and fans encoded frames out to the live clients."""

    def __init__(self, frame_rate_hz: float = 25.0, max_queue: int = 50, stall_timeout_s: float = 5.0,
                 max_samples_per_frame: int | None = 4000):
        if not 1.0 <= frame_rate_hz <= 60.0:
            raise ValueError(f"frame rate {frame_rate_hz} Hz outside 1…60 Hz")
        if max_samples_per_frame is not None and max_samples_per_frame < 2 * len(DECIMATION_KEYS):
            raise ValueError(f"max_samples_per_frame {max_samples_per_frame} < {2 * len(DECIMATION_KEYS)}")
        self.frame_rate_hz = frame_rate_hz
        self.max_samples_per_frame = max_samples_per_frame
        self.samples_decimated_total = 0  # samples left out of live frames (all are recorded)
        self.max_queue = max_queue
        self.stall_timeout_s = stall_timeout_s
        self.sequence = 0
        self.samples_total = 0
        self.frames_total = 0
        self.evicted_total = 0
        self.dropped_by_departed = 0
        self.clients: set[LiveClient] = set()
        self._pending: list[Mapping[str, np.ndarray]] = []
        self._lock = threading.Lock()
        self._rate_window: deque[tuple[float, int]] = deque(maxlen=64)
        self._client_counter = 0

    # -- producer side (any thread) --------------------------------------------------------------------------
    def publish(self, columns: Mapping[str, np.ndarray]) -> None:
        """Hand over one batch (channel → array, the names of :data:`LIVE_CHANNELS`); returns at once."""
        n = len(columns["time_s"])
        if n == 0:
            return
        with self._lock:
            self._pending.append(columns)
            self.samples_total += n

    # -- event-loop side -------------------------------------------------------------------------------------
    def _take_pending(self) -> dict[str, np.ndarray] | None:
        with self._lock:
            batches, self._pending = self._pending, []
        if not batches:
            return None
        if len(batches) == 1:
            return dict(batches[0])
        return {name: np.concatenate([b[name] for b in batches]) for name, _, _ in LIVE_CHANNELS}

    def tick(self) -> bytes | None:
        """Encode whatever arrived since the last tick into one frame and offer it to every client."""
        columns = self._take_pending()
        now = time.monotonic()
        self._rate_window.append((now, self.samples_total))
        if columns is None:
            return None
        if self.max_samples_per_frame is not None:
            rows = minmax_rows(columns, self.max_samples_per_frame)
            if rows is not None:
                self.samples_decimated_total += len(columns["time_s"]) - len(rows)
                columns = {name: np.asarray(columns[name])[rows] for name, _, _ in LIVE_CHANNELS}
        self.sequence += 1
        frame = encode_frame(self.sequence, columns)
        self.frames_total += 1
        for client in tuple(self.clients):
            client.offer(frame)
        return frame

    async def run(self) -> None:
        """The framer: ticks at ``frame_rate_hz`` on a fixed schedule until cancelled."""
        loop = asyncio.get_running_loop()
        period = 1.0 / self.frame_rate_hz
        next_t = loop.time()
        while True:
            next_t += period
            self.tick()
            delay = next_t - loop.time()
            if delay < -period:  # fell behind (e.g. a long GC pause): re-anchor instead of bursting
                next_t = loop.time()
                delay = 0.0
            await asyncio.sleep(max(delay, 0.0))

    def acquisition_rate_hz(self) -> float:
        """Samples/s published over the last few seconds (0 when idle)."""
        if len(self._rate_window) < 2:
            return 0.0
        (t_a, n_a), (t_b, n_b) = self._rate_window[0], self._rate_window[-1]
        return (n_b - n_a) / (t_b - t_a) if t_b > t_a else 0.0

    def add_client(self, send: Callable[[bytes], Awaitable[None]]) -> LiveClient:
        self._client_counter += 1
        client = LiveClient(
            send, name=f"live-{self._client_counter}", max_queue=self.max_queue, stall_timeout_s=self.stall_timeout_s
        )
        self.clients.add(client)
        return client

    def remove_client(self, client: LiveClient) -> None:
        if client in self.clients:
            self.clients.discard(client)
            self.dropped_by_departed += client.dropped
            if client.evicted:
                self.evicted_total += 1
        client.close()

    def dropped_total(self) -> int:
        return self.dropped_by_departed + sum(c.dropped for c in self.clients)

    def client_stats(self) -> list[dict]:
        return [
            {"name": c.name, "sent": c.sent, "dropped": c.dropped, "queued": c.queued}
            for c in sorted(self.clients, key=lambda c: c.connected_at)
        ]

    async def serve(self, send: Callable[[bytes], Awaitable[None]], wait_closed: Awaitable[None]) -> LiveClient:
        """Register a client, run its sender until it is evicted or ``wait_closed`` finishes (disconnect)."""
        client = self.add_client(send)
        try:
            await run_until_either(client.run(), wait_closed)
        finally:
            self.remove_client(client)
        return client

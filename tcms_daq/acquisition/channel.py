"""An acquisition channel's book-keeping (one instrument's pending batches, errors, arrivals) and the guarded
status read of a drive that the loader's and the input drive's pollers share."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import TypeVar

import numpy as np

from tcms_daq.drivers.base import Batch, Disconnected, InstrumentError, concat_common_columns

_Status = TypeVar("_Status")


class Channel:
    """Book-keeping for one instrument: pending batches, errors in a row, last arrival (clock time)."""

    def __init__(self, kind: str, name: str, now_s: float):
        self.kind = kind
        self.name = name
        self.pending: list[Batch] = []
        self.lock = threading.Lock()
        self.errors_in_row = 0
        self.errors_total = 0
        self.readings = 0
        self.last_arrival_s = now_s
        self.last_arrival_real_s: float | None = None  # time.monotonic() of the last reading (None: none yet)
        self.last_value: float | None = None
        self.last_input_arcsec: float | None = None  # an angle pair source's latest input angle
        self.last_error: str | None = None
        self.busy_since: float | None = None  # clock time the pending request started

    def take(self) -> tuple[Batch, dict[str, np.ndarray]]:
        """The pending readings as one batch, and the extra columns all of them carry."""
        with self.lock:
            parts, self.pending = self.pending, []
        if not parts:
            return Batch.empty(), {}
        extra = concat_common_columns([getattr(p, "extra", None) or {} for p in parts])
        if len(parts) == 1:
            return parts[0], extra
        return Batch(np.concatenate([p.time_s for p in parts]), np.concatenate([p.value for p in parts])), extra


def guarded_status(ch: Channel, lock: threading.RLock, read: Callable[[], _Status], *, now: Callable[[], float],
                   on_error: Callable[[Channel, Exception], None], wait_for_lock: bool) -> _Status | None:
    """One status read of a drive under its lock, with the channel's book-keeping (a failure goes to ``on_error``,
    the loop's judgement of the channel's errors; a success counts as its reading at ``now()``, clock time): None
    when it failed, or when the lock is held and ``wait_for_lock`` is False (a command is in progress: the poll is
    skipped, not queued)."""
    if not lock.acquire(blocking=wait_for_lock):
        return None
    ch.busy_since = now()  # the drive is busy from here until it answers
    try:
        status = read()
    except InstrumentError as exc:
        on_error(ch, exc)
        return None
    except Exception as exc:  # a driver bug is a lost instrument, not a crash of the loop
        on_error(ch, Disconnected(ch.name, f"{type(exc).__name__}: {exc}"))
        return None
    finally:
        ch.busy_since = None
        lock.release()
    ch.errors_in_row = 0
    ch.readings += 1
    ch.last_arrival_s = now()
    ch.last_arrival_real_s = time.monotonic()
    return status

"""The recorder: a lossless subscriber that writes a run's batches to the store from its own thread.

The acquisition thread only appends a reference to the batch to an in-memory list (no I/O, never blocks on the
database); a writer thread commits what has accumulated every ``flush_interval_s`` in one transaction, so a
crash loses at most that interval of samples.
"""

from __future__ import annotations

import threading
from collections.abc import Mapping

import numpy as np

from tcms_daq.store.base import Store


class Recorder:
    """Buffers column batches of one run and commits them to ``store`` in the background."""

    def __init__(self, store: Store, run_id: str, flush_interval_s: float = 0.2):
        self.store = store
        self.run_id = run_id
        self.flush_interval_s = flush_interval_s
        self.samples_written = 0
        self.error: BaseException | None = None
        self._pending: list[Mapping[str, np.ndarray]] = []
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name=f"recorder-{run_id}", daemon=True)
        self._thread.start()

    def write(self, columns: Mapping[str, np.ndarray]) -> None:
        """Queue one batch (channel → array); called from the acquisition thread, returns at once."""
        with self._lock:
            self._pending.append(columns)

    def flush(self) -> int:
        with self._lock:
            batches, self._pending = self._pending, []
        if not batches:
            return 0
        n = self.store.append_samples(self.run_id, batches)
        self.samples_written += n
        return n

    def _loop(self) -> None:
        while not self._stop.wait(self.flush_interval_s):
            try:
                self.flush()
            except BaseException as exc:  # kept and re-raised by close(): the raw-data sink is critical
                self.error = exc
                return

    def close(self) -> int:
        """Stop the writer thread, commit what is left; raises if a write failed. Returns samples written."""
        self._stop.set()
        self._thread.join()
        if self.error is not None:
            raise self.error
        self.flush()
        return self.samples_written

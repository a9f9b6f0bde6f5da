"""Persistent run store (SQLite, WAL) and the recorder that feeds it from the acquisition path."""

from tcms_daq.store.recorder import Recorder
from tcms_daq.store.sqlite_store import (
    ACTIVE_STATUSES,
    FINAL_STATUSES,
    RUN_STATUSES,
    STORE_FILENAME,
    RunStore,
    StoredRun,
    StoreError,
    new_run_id,
)

__all__ = [
    "ACTIVE_STATUSES",
    "FINAL_STATUSES",
    "RUN_STATUSES",
    "STORE_FILENAME",
    "Recorder",
    "StoredRun",
    "RunStore",
    "StoreError",
    "new_run_id",
]

"""Persistent run stores behind one interface (:class:`Store`): SQLite (WAL, one file per bench, the default)
and PostgreSQL (a plant's benches sharing one database); the recorder that feeds them from the acquisition path;
:func:`open_store` picks the backend from a store URL."""

from tcms_daq.store.base import (
    ACTIVE_STATUSES,
    FINAL_STATUSES,
    RUN_STATUSES,
    VERDICTS,
    BenchModelVersion,
    CompensationVersion,
    RunQuery,
    Store,
    StoredRun,
    StoreError,
    new_run_id,
)
from tcms_daq.store.opening import open_store, redact_url
from tcms_daq.store.recorder import Recorder
from tcms_daq.store.sqlite_store import STORE_FILENAME, RunStore

__all__ = [
    "ACTIVE_STATUSES",
    "FINAL_STATUSES",
    "RUN_STATUSES",
    "STORE_FILENAME",
    "VERDICTS",
    "BenchModelVersion",
    "CompensationVersion",
    "Recorder",
    "RunQuery",
    "RunStore",
    "Store",
    "StoredRun",
    "StoreError",
    "new_run_id",
    "open_store",
    "redact_url",
]

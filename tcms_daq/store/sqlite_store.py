"""The run store: one SQLite database in WAL mode holding run records and their samples.

A run record carries the request (reducer, profile parameters, operator …), the generated profile, the status,
the evaluation results, a snapshot of the bench configuration and the compensator (TOML) used. Samples are
stored in batches: each batch row is one little-endian float64 blob, channel-major, with the run's channel
names kept on the run record. A committed batch survives a crash of the process (WAL, ``synchronous=NORMAL``).

Opening the store marks runs left ``queued`` or ``running`` by a previous process as ``interrupted``; their
samples are kept. Only the service does that: a reader beside a running service (``tcms discrepancy --run``)
opens with ``recover=False`` and leaves the active run alone.
"""

from __future__ import annotations

import json
import sqlite3
import threading
import time
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from tcms_daq.identity import decision
from tcms_daq.store.base import (
    ACTIVE_STATUSES,
    EXACT_TOTAL_UP_TO,
    FINAL_STATUSES,
    INTERRUPTED_ERROR,
    RUN_STATUSES,
    VERSIONED,
    BenchModelVersion,
    CompensationVersion,
    HeadlineSeries,
    RunColumns,
    RunQuery,
    RunTotal,
    StoredRun,
    StoredSamples,
    StoreError,
    VersionedDocuments,
    brief_results,
    check_new_run,
    dumps,
    new_run_id,
    pack_batches,
    status_update,
    text_sha256,
)
from tcms_daq.store.people import SQLITE_SCHEMA as _PEOPLE_SCHEMA
from tcms_daq.store.people import BenchSettingsRecords

__all__ = ["ACTIVE_STATUSES", "FINAL_STATUSES", "RUN_STATUSES", "STORE_FILENAME", "BenchModelVersion",
           "CompensationVersion", "RunStore", "StoreError", "StoredRun", "new_run_id", "text_sha256"]

_SCHEMA = """
CREATE TABLE IF NOT EXISTS runs (
    id TEXT PRIMARY KEY,
    created_at REAL NOT NULL,
    started_at REAL,
    finished_at REAL,
    status TEXT NOT NULL,
    request TEXT NOT NULL,
    profile TEXT,
    results TEXT,
    error TEXT,
    config_snapshot TEXT,
    compensator_toml TEXT,
    channels TEXT NOT NULL,
    sample_count INTEGER NOT NULL DEFAULT 0
);
CREATE INDEX IF NOT EXISTS runs_created ON runs(created_at);
CREATE TABLE IF NOT EXISTS compensations (
    version INTEGER PRIMARY KEY AUTOINCREMENT,
    created_at REAL NOT NULL,
    note TEXT NOT NULL,
    sha256 TEXT NOT NULL,
    toml TEXT NOT NULL,
    rollback_of INTEGER
);
CREATE TABLE IF NOT EXISTS bench_models (
    version INTEGER PRIMARY KEY AUTOINCREMENT,
    created_at REAL NOT NULL,
    note TEXT NOT NULL,
    sha256 TEXT NOT NULL,
    toml TEXT NOT NULL,
    analysis_id TEXT,
    run_id TEXT
);
CREATE TABLE IF NOT EXISTS te_models (
    version INTEGER PRIMARY KEY AUTOINCREMENT,
    created_at REAL NOT NULL,
    note TEXT NOT NULL,
    sha256 TEXT NOT NULL,
    toml TEXT NOT NULL,
    bench_id TEXT,
    analysis_id TEXT,
    run_id TEXT
);
CREATE TABLE IF NOT EXISTS sample_batches (
    run_id TEXT NOT NULL REFERENCES runs(id) ON DELETE CASCADE,
    batch_index INTEGER NOT NULL,
    n_samples INTEGER NOT NULL,
    data BLOB NOT NULL,
    PRIMARY KEY (run_id, batch_index)
);
"""

# Columns added since the first schema: (table, column, type). Added on open when missing; the searchable run
# columns of an older store are filled from its JSON request and results.
_ADDED_COLUMNS: tuple[tuple[str, str, str], ...] = (
    ("runs", "compensation_version", "INTEGER"),
    ("runs", "bench_id", "TEXT"),
    ("runs", "bench_name", "TEXT"),
    ("runs", "reducer", "TEXT"),
    ("runs", "serial_number", "TEXT"),
    ("runs", "operator", "TEXT"),
    ("runs", "verdict", "TEXT"),
    ("compensations", "bench_id", "TEXT"),
    ("bench_models", "bench_id", "TEXT"),
)
_RUN_COLUMNS = ("id, created_at, started_at, finished_at, status, request, profile, results, error, "
                "config_snapshot, compensator_toml, channels, sample_count, compensation_version, bench_id, "
                "bench_name")
_LIST_COLUMNS = _RUN_COLUMNS.replace("config_snapshot, compensator_toml", "NULL, NULL")


MAX_IDLE_CONNECTIONS = 4  # connections kept open between calls (more are opened while that many are busy)

#: file name of the run store inside a data directory (``tcms serve --data-dir``)
STORE_FILENAME = "tcms-runs.sqlite3"


def _loads(text: str | None) -> Any:
    return None if text is None else json.loads(text)


class RunStore(VersionedDocuments, StoredSamples, HeadlineSeries, BenchSettingsRecords):
    """SQLite (WAL) store of runs and samples; safe to use from several threads.

    Connections come from a small pool (WAL lets readers run beside the one writer): a call takes an idle one
    (or opens one) and gives it back; at most ``MAX_IDLE_CONNECTIONS`` stay open between calls, so the threads
    that come and go (one recorder per test) leave no file descriptors behind. Writes are serialised by a lock
    so batches of one run keep their order. Opened for a bench (``bench_id``, ``bench_name``), it
    records that bench on every run it creates and keeps that bench's versioned documents; without one it is a
    store of one bench as before fleets (every run and document is its own).
    """

    def __init__(self, path: str | Path, *, recover: bool = True, synchronous: str = "NORMAL",
                 bench_id: str | None = None, bench_name: str | None = None):
        """``synchronous``: SQLite's durability level in WAL mode — ``NORMAL`` (a commit survives a crash of the
        process) or ``FULL`` (also a power cut: every commit is synced to the disk). ``recover``: mark the runs
        a dead service left active (of this bench, and those recorded before benches) as ``interrupted``."""
        if synchronous not in ("NORMAL", "FULL"):
            raise ValueError(f"synchronous must be NORMAL or FULL, got {synchronous!r}")
        self.synchronous = synchronous
        self.path = Path(path)
        self.bench_id = bench_id
        self.bench_name = bench_name
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._idle: list[sqlite3.Connection] = []  # open and not in use
        self._open = 0  # connections open (idle or in use)
        self._conn_lock = threading.Lock()
        self._write_lock = threading.Lock()
        self._closed = False
        self._migrate()
        self.recovered_run_ids: list[str] = self._mark_interrupted() if recover else []

    def describe(self) -> str:
        return str(self.path.resolve())

    def _migrate(self) -> None:
        with self._write_lock, self._connection() as conn:
            conn.executescript(_SCHEMA)
            conn.executescript(_PEOPLE_SCHEMA)
            for table, column, kind in _ADDED_COLUMNS:
                if column not in {row[1] for row in conn.execute(f"PRAGMA table_info({table})")}:
                    conn.execute(f"ALTER TABLE {table} ADD COLUMN {column} {kind}")
            pending = conn.execute("SELECT id, request, results FROM runs WHERE reducer IS NULL AND verdict IS NULL "
                                   "AND serial_number IS NULL AND request != '{}'").fetchall()
            for run_id, request, results in pending:  # runs stored before the searchable columns
                cols = RunColumns.of(_loads(request) or {})
                conn.execute("UPDATE runs SET reducer=?, serial_number=?, operator=?, verdict=? WHERE id=?",
                             (cols.reducer, cols.serial_number, cols.operator, decision(_loads(results)), run_id))
            for index in ("runs_bench ON runs(bench_id, created_at)", "runs_serial ON runs(serial_number)",
                          "runs_reducer ON runs(reducer)"):
                conn.execute(f"CREATE INDEX IF NOT EXISTS {index}")

    # -- connections -----------------------------------------------------------------------------------------
    def _new_connection(self) -> sqlite3.Connection:
        conn = sqlite3.connect(self.path, timeout=30.0, check_same_thread=False, isolation_level=None)
        conn.execute("PRAGMA journal_mode=WAL")
        conn.execute(f"PRAGMA synchronous={self.synchronous}")
        conn.execute("PRAGMA foreign_keys=ON")
        return conn

    @contextmanager
    def _connection(self) -> Iterator[sqlite3.Connection]:
        """An idle pooled connection (or a new one) for one call; given back (or closed when enough are idle)."""
        with self._conn_lock:
            if self._closed:
                raise StoreError(f"run store {self.path} is closed")
            conn = self._idle.pop() if self._idle else None
            if conn is None:
                self._open += 1
        if conn is None:
            try:
                conn = self._new_connection()
            except BaseException:
                with self._conn_lock:
                    self._open -= 1
                raise
        try:
            yield conn
        finally:
            with self._conn_lock:
                keep = not self._closed and len(self._idle) < MAX_IDLE_CONNECTIONS
                if keep:
                    self._idle.append(conn)
                else:
                    self._open -= 1
            if not keep:
                conn.close()

    @property
    def open_connections(self) -> int:
        """Connections open now (idle in the pool or in use)."""
        return self._open

    def _query(self, sql: str, params: Sequence[Any] = ()) -> list[Any]:
        """All rows of a read."""
        with self._connection() as conn:
            return conn.execute(sql, params).fetchall()

    def close(self) -> None:
        with self._conn_lock:
            self._closed = True
            idle, self._idle = self._idle, []
            self._open -= len(idle)
        for conn in idle:  # a connection in use is closed when its call gives it back
            try:
                conn.close()
            except sqlite3.ProgrammingError:
                pass

    def __enter__(self) -> RunStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _write(self, sql: str, params: Sequence[Any] = ()) -> tuple[int, int | None]:
        """(rowcount, lastrowid) of one write."""
        with self._write_lock, self._connection() as conn:
            cur = conn.execute(sql, params)
            return cur.rowcount, cur.lastrowid

    def _own(self, column: str = "bench_id") -> tuple[str, tuple[Any, ...]]:
        """SQL condition (and parameters) selecting this bench's rows and those recorded before benches."""
        if self.bench_id is None:
            return "1=1", ()
        return f"({column} = ? OR {column} IS NULL)", (self.bench_id,)

    # -- runs ------------------------------------------------------------------------------------------------
    def _mark_interrupted(self) -> list[str]:
        own, own_params = self._own()
        with self._write_lock, self._connection() as conn:
            rows = conn.execute(
                f"SELECT id FROM runs WHERE status IN (?, ?) AND {own} ORDER BY created_at",
                (*ACTIVE_STATUSES, *own_params),
            ).fetchall()
            ids = [r[0] for r in rows]
            if ids:
                conn.execute(
                    "UPDATE runs SET status='interrupted', finished_at=COALESCE(finished_at, ?), "
                    f"error=COALESCE(error, ?) WHERE status IN (?, ?) AND {own}",
                    (time.time(), INTERRUPTED_ERROR, *ACTIVE_STATUSES, *own_params),
                )
        return ids

    def create_run(
        self,
        run_id: str,
        request: Mapping[str, Any],
        channels: Sequence[str],
        *,
        profile: Mapping[str, Any] | None = None,
        config_snapshot: Mapping[str, Any] | None = None,
        compensator_toml: str | None = None,
        compensation_version: int | None = None,
        status: str = "queued",
    ) -> StoredRun:
        check_new_run(run_id, channels, status)
        cols = RunColumns.of(request)
        try:
            self._write(
                "INSERT INTO runs (id, created_at, status, request, profile, config_snapshot, compensator_toml, "
                "channels, compensation_version, bench_id, bench_name, reducer, serial_number, operator) "
                "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                (
                    run_id,
                    time.time(),
                    status,
                    dumps(dict(request)),
                    dumps(None if profile is None else dict(profile)),
                    dumps(None if config_snapshot is None else dict(config_snapshot)),
                    compensator_toml,
                    json.dumps(list(channels)),
                    compensation_version,
                    self.bench_id,
                    self.bench_name,
                    cols.reducer,
                    cols.serial_number,
                    cols.operator,
                ),
            )
        except sqlite3.IntegrityError:
            raise StoreError(f"run {run_id} already exists") from None
        return self.get_run(run_id)  # type: ignore[return-value]

    def set_status(
        self,
        run_id: str,
        status: str,
        *,
        error: str | None = None,
        results: Mapping[str, Any] | None = None,
    ) -> None:
        """Move a run to ``status`` (:func:`~tcms_daq.store.base.status_update`)."""
        sets, params = status_update(status, error=error, results=results,
                                     encode_results=lambda r: dumps(dict(r)), placeholder="?")
        params.append(run_id)
        rowcount, _ = self._write(f"UPDATE runs SET {sets} WHERE id=?", params)
        if rowcount == 0:
            raise StoreError(f"unknown run {run_id!r}")

    # -- versioned TOML documents: compensations and bench models ------------------------------------------
    # Both tables hold (version, created_at, note, sha256, toml, bench_id, <provenance columns>); one way to add
    # and read. A bench sees its own versions (and those kept before benches were recorded).
    def _add_version(self, table: str, toml: str, note: str, provenance: Sequence[Any]) -> tuple[int, float]:
        columns = ("created_at", "note", "sha256", "toml", "bench_id", *VERSIONED[table])
        created = time.time()
        _, rowid = self._write(f"INSERT INTO {table} ({', '.join(columns)}) VALUES ({', '.join('?' * len(columns))})",
                               (created, note, text_sha256(toml), toml, self.bench_id, *provenance))
        assert rowid is not None  # an INSERT into a rowid table always has one
        return rowid, created

    def _history(self, table: str, limit: int) -> list[tuple[Any, ...]]:
        columns = ("version", "created_at", "note", "sha256", *VERSIONED[table])
        own, own_params = self._own()
        return self._query(f"SELECT {', '.join(columns)} FROM {table} WHERE {own} ORDER BY version DESC LIMIT ?",
                           (*own_params, limit))

    def _version(self, table: str, version: int | None) -> tuple[Any, ...] | None:
        """The row (header columns…, toml) of ``version`` (default: the latest) of this bench."""
        own, own_params = self._own()
        sql = (f"SELECT {', '.join(('version', 'created_at', 'note', 'sha256', *VERSIONED[table]))}, toml "
               f"FROM {table} WHERE {own} ")
        rows = (self._query(sql + "AND version=?", (*own_params, version)) if version is not None
                else self._query(sql + "ORDER BY version DESC LIMIT 1", own_params))
        return rows[0] if rows else None

    # -- people (users, audit, plans: tcms_daq.store.people) ------------------------------------------------
    def _people_query(self, sql: str, params: Sequence[Any] = ()) -> list[tuple[Any, ...]]:
        return [tuple(r) for r in self._query(sql, params)]

    def _people_execute(self, sql: str, params: Sequence[Any] = ()) -> int:
        try:
            return self._write(sql, params)[0]
        except sqlite3.IntegrityError as exc:
            raise StoreError(f"refused by the run store: {exc}") from None

    # -- runs (reading) --------------------------------------------------------------------------------------
    def get_run(self, run_id: str) -> StoredRun | None:
        rows = self._query(f"SELECT {_RUN_COLUMNS} FROM runs WHERE id=?", (run_id,))
        return _record(rows[0]) if rows else None

    def list_runs(self, limit: int = 100, offset: int = 0, query: RunQuery | None = None, *,
                  brief: bool = False) -> list[StoredRun]:
        """Runs of every bench matching ``query``, newest first (without their config snapshot and TOML; ``brief``:
        results reduced to :func:`~tcms_daq.store.base.brief_results`)."""
        where, params = (query or RunQuery()).where("?", "LIKE")
        rows = self._query(f"SELECT {_LIST_COLUMNS} FROM runs {where} ORDER BY created_at DESC, id DESC LIMIT ? OFFSET ?",
                           (*params, limit, offset))
        records = [_record(r) for r in rows]
        return [replace(r, results=brief_results(r.results)) for r in records] if brief else records

    def count_runs(self, query: RunQuery | None = None) -> int:
        where, params = (query or RunQuery()).where("?", "LIKE")
        return int(self._query(f"SELECT COUNT(*) FROM runs {where}", params)[0][0])

    def total_runs(self, query: RunQuery | None = None, exact_up_to: int = EXACT_TOTAL_UP_TO) -> RunTotal:
        """Always exact: one bench's file counts its runs quickly."""
        return RunTotal(self.count_runs(query))

    def count_by_status(self) -> dict[str, int]:
        """Runs of this bench (and those recorded before benches) by status."""
        counts = dict.fromkeys(RUN_STATUSES, 0)
        own, own_params = self._own()
        for status, n in self._query(f"SELECT status, COUNT(*) FROM runs WHERE {own} GROUP BY status", own_params):
            counts[status] = n
        return counts

    # -- samples ---------------------------------------------------------------------------------------------
    def append_samples(self, run_id: str, batches: Sequence[Mapping[str, np.ndarray]]) -> int:
        """Append column batches (each a mapping channel → array, the run's channels) in one transaction.

        Returns the number of samples written.
        """
        if not batches:
            return 0
        rows = pack_batches(run_id, self._channels(run_id), batches)
        if not rows:
            return 0
        total = sum(n for n, _ in rows)
        with self._write_lock, self._connection() as conn:
            conn.execute("BEGIN IMMEDIATE")
            try:
                start = conn.execute(
                    "SELECT COALESCE(MAX(batch_index) + 1, 0) FROM sample_batches WHERE run_id=?", (run_id,)
                ).fetchone()[0]
                conn.executemany(
                    "INSERT INTO sample_batches (run_id, batch_index, n_samples, data) VALUES (?, ?, ?, ?)",
                    [(run_id, start + i, n, blob) for i, (n, blob) in enumerate(rows)],
                )
                conn.execute("UPDATE runs SET sample_count = sample_count + ? WHERE id=?", (total, run_id))
                conn.execute("COMMIT")
            except BaseException:
                conn.execute("ROLLBACK")
                raise
        return total

    def _channels(self, run_id: str) -> tuple[str, ...]:
        rows = self._query("SELECT channels FROM runs WHERE id=?", (run_id,))
        if not rows:
            raise StoreError(f"unknown run {run_id!r}")
        return tuple(json.loads(rows[0][0]))

    def _batch_rows(self, run_id: str, from_index: int, limit: int) -> list[tuple[Any, ...]]:
        return self._query("SELECT batch_index, n_samples, data FROM sample_batches WHERE run_id=? AND batch_index >= ? "
                           "ORDER BY batch_index LIMIT ?", (run_id, from_index, limit))


def _record(row: Sequence[Any]) -> StoredRun:
    return StoredRun(
        id=row[0],
        created_at=row[1],
        started_at=row[2],
        finished_at=row[3],
        status=row[4],
        request=_loads(row[5]) or {},
        profile=_loads(row[6]),
        results=_loads(row[7]),
        error=row[8],
        config_snapshot=_loads(row[9]),
        compensator_toml=row[10],
        channels=tuple(json.loads(row[11])),
        sample_count=row[12],
        compensation_version=row[13],
        bench_id=row[14],
        bench_name=row[15],
    )

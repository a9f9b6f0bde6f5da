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

import hashlib
import json
import sqlite3
import threading
import time
import uuid
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from tcms_daq.errors import TcmsError
from tcms_daq.runstate import STORED, STORED_ACTIVE, STORED_FINAL
from tcms_daq.samples import Samples, samples_from_columns

RUN_STATUSES: tuple[str, ...] = STORED  # tcms_daq.runstate.RunState: one vocabulary
ACTIVE_STATUSES: tuple[str, ...] = STORED_ACTIVE
FINAL_STATUSES: tuple[str, ...] = STORED_FINAL

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
CREATE TABLE IF NOT EXISTS sample_batches (
    run_id TEXT NOT NULL REFERENCES runs(id) ON DELETE CASCADE,
    batch_index INTEGER NOT NULL,
    n_samples INTEGER NOT NULL,
    data BLOB NOT NULL,
    PRIMARY KEY (run_id, batch_index)
);
"""

_LE_F64 = np.dtype("<f8")


#: file name of the run store inside a data directory (``tcms serve --data-dir``)
STORE_FILENAME = "tcms-runs.sqlite3"


class StoreError(TcmsError):
    """The run store cannot do what was asked (unknown run, bad channel set, closed store)."""


@dataclass(frozen=True)
class StoredRun:
    """One run as read from the store. Times are UNIX seconds (UTC)."""

    id: str
    created_at: float
    started_at: float | None
    finished_at: float | None
    status: str
    request: dict[str, Any]
    profile: dict[str, Any] | None
    results: dict[str, Any] | None
    error: str | None
    config_snapshot: dict[str, Any] | None
    compensator_toml: str | None
    channels: tuple[str, ...]
    sample_count: int
    compensation_version: int | None = None  # the accepted upload in use (None: the bench config's file)

    def summary(self) -> dict[str, Any]:
        """The JSON view used by the REST API (everything but the large snapshot fields)."""
        return {
            "id": self.id,
            "status": self.status,
            "created_at": _iso(self.created_at),
            "started_at": _iso(self.started_at),
            "finished_at": _iso(self.finished_at),
            "request": self.request,
            "results": self.results,
            "error": self.error,
            "sample_count": self.sample_count,
            "channels": list(self.channels),
            "compensation_version": self.compensation_version,
            "compensation_sha256": None if self.compensator_toml is None else text_sha256(self.compensator_toml),
        }


def text_sha256(text: str) -> str:
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


@dataclass(frozen=True)
class CompensationVersion:
    """One accepted compensation upload (the TOML as the service applied it), or a rollback to an earlier one."""

    version: int
    created_at: float
    note: str
    sha256: str
    rollback_of: int | None = None

    def summary(self) -> dict[str, Any]:
        return {"version": self.version, "created_at": _iso(self.created_at), "note": self.note,
                "sha256": self.sha256, "rollback_of": self.rollback_of}


@dataclass(frozen=True)
class BenchModelVersion:
    """One version of the bench model: the effects accepted into it (a discrepancy model TOML) and where they
    came from (the analysis of which run). Version 0, the catalogue reducer's model alone, is not stored."""

    version: int
    created_at: float
    note: str
    sha256: str
    analysis_id: str | None = None
    run_id: str | None = None

    def summary(self) -> dict[str, Any]:
        return {"version": self.version, "created_at": _iso(self.created_at), "note": self.note,
                "sha256": self.sha256, "analysis_id": self.analysis_id, "run_id": self.run_id}


def _iso(t: float | None) -> str | None:
    return None if t is None else datetime.fromtimestamp(t, UTC).isoformat(timespec="milliseconds")


def new_run_id() -> str:
    """A time-sortable, human-readable run id: ``20261121-153012-1a2b3c``."""
    return f"{datetime.now(UTC):%Y%m%d-%H%M%S}-{uuid.uuid4().hex[:6]}"


def _dumps(obj: Any) -> str | None:
    return None if obj is None else json.dumps(obj, allow_nan=False, default=_json_default)


def _json_default(obj: Any) -> Any:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


def _loads(text: str | None) -> Any:
    return None if text is None else json.loads(text)


class RunStore:
    """SQLite (WAL) store of runs and samples; safe to use from several threads.

    Each thread gets its own connection (WAL lets readers run beside the one writer); writes are serialised
    by a lock so batches of one run keep their order.
    """

    def __init__(self, path: str | Path, *, recover: bool = True, synchronous: str = "NORMAL"):
        """``synchronous``: SQLite's durability level in WAL mode — ``NORMAL`` (a commit survives a crash of the
        process) or ``FULL`` (also a power cut: every commit is synced to the disk)."""
        if synchronous not in ("NORMAL", "FULL"):
            raise ValueError(f"synchronous must be NORMAL or FULL, got {synchronous!r}")
        self.synchronous = synchronous
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._local = threading.local()
        self._connections: list[sqlite3.Connection] = []
        self._conn_lock = threading.Lock()
        self._write_lock = threading.Lock()
        self._closed = False
        conn = self._conn()
        conn.executescript(_SCHEMA)
        columns = {row[1] for row in conn.execute("PRAGMA table_info(runs)")}
        if "compensation_version" not in columns:  # a store from before compensation versions
            conn.execute("ALTER TABLE runs ADD COLUMN compensation_version INTEGER")
        self.recovered_run_ids: list[str] = self._mark_interrupted() if recover else []

    # -- connections -----------------------------------------------------------------------------------------
    def _conn(self) -> sqlite3.Connection:
        if self._closed:
            raise StoreError(f"run store {self.path} is closed")
        conn = getattr(self._local, "conn", None)
        if conn is None:
            conn = sqlite3.connect(self.path, timeout=30.0, check_same_thread=False, isolation_level=None)
            conn.execute("PRAGMA journal_mode=WAL")
            conn.execute(f"PRAGMA synchronous={self.synchronous}")
            conn.execute("PRAGMA foreign_keys=ON")
            self._local.conn = conn
            with self._conn_lock:
                self._connections.append(conn)
        return conn

    def close(self) -> None:
        with self._conn_lock:
            for conn in self._connections:
                try:
                    conn.close()
                except sqlite3.ProgrammingError:
                    pass
            self._connections.clear()
        self._closed = True

    def __enter__(self) -> RunStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _write(self, sql: str, params: Sequence[Any] = ()) -> sqlite3.Cursor:
        with self._write_lock:
            return self._conn().execute(sql, params)

    # -- runs ------------------------------------------------------------------------------------------------
    def _mark_interrupted(self) -> list[str]:
        conn = self._conn()
        rows = conn.execute(
            "SELECT id FROM runs WHERE status IN (?, ?) ORDER BY created_at", ACTIVE_STATUSES
        ).fetchall()
        ids = [r[0] for r in rows]
        if ids:
            with self._write_lock:
                conn.execute(
                    "UPDATE runs SET status='interrupted', finished_at=COALESCE(finished_at, ?), "
                    "error=COALESCE(error, 'the service stopped while this run was active') "
                    "WHERE status IN (?, ?)",
                    (time.time(), *ACTIVE_STATUSES),
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
        if status not in RUN_STATUSES:
            raise StoreError(f"unknown run status {status!r}")
        if not channels or len(set(channels)) != len(channels):
            raise StoreError(f"run {run_id}: channel names must be unique and non-empty, got {list(channels)}")
        try:
            self._write(
                "INSERT INTO runs (id, created_at, status, request, profile, config_snapshot, compensator_toml, "
                "channels, compensation_version) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)",
                (
                    run_id,
                    time.time(),
                    status,
                    _dumps(dict(request)),
                    _dumps(None if profile is None else dict(profile)),
                    _dumps(None if config_snapshot is None else dict(config_snapshot)),
                    compensator_toml,
                    json.dumps(list(channels)),
                    compensation_version,
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
        """Move a run to ``status``; ``running`` stamps the start time, a final status the finish time."""
        if status not in RUN_STATUSES:
            raise StoreError(f"unknown run status {status!r}")
        now = time.time()
        sets = ["status=?"]
        params: list[Any] = [status]
        if status == "running":
            sets.append("started_at=COALESCE(started_at, ?)")
            params.append(now)
        if status in FINAL_STATUSES:
            sets.append("finished_at=?")
            params.append(now)
        if error is not None:
            sets.append("error=?")
            params.append(error)
        if results is not None:
            sets.append("results=?")
            params.append(_dumps(dict(results)))
        params.append(run_id)
        cur = self._write(f"UPDATE runs SET {', '.join(sets)} WHERE id=?", params)
        if cur.rowcount == 0:
            raise StoreError(f"unknown run {run_id!r}")

    # -- versioned TOML documents: compensations and bench models ------------------------------------------
    # Both tables hold (version, created_at, note, sha256, toml, <provenance columns>); one way to add and read.
    _VERSIONED: dict[str, tuple[str, ...]] = {"compensations": ("rollback_of",),
                                              "bench_models": ("analysis_id", "run_id")}

    def _add_version(self, table: str, toml: str, note: str, provenance: Sequence[Any]) -> tuple[int, float]:
        columns = ("created_at", "note", "sha256", "toml", *self._VERSIONED[table])
        created = time.time()
        cur = self._write(f"INSERT INTO {table} ({', '.join(columns)}) VALUES ({', '.join('?' * len(columns))})",
                          (created, note, text_sha256(toml), toml, *provenance))
        assert cur.lastrowid is not None  # an INSERT into a rowid table always has one
        return cur.lastrowid, created

    def _history(self, table: str, limit: int) -> list[tuple[Any, ...]]:
        columns = ("version", "created_at", "note", "sha256", *self._VERSIONED[table])
        return self._conn().execute(f"SELECT {', '.join(columns)} FROM {table} ORDER BY version DESC LIMIT ?",
                                    (limit,)).fetchall()

    def _version(self, table: str, version: int | None) -> tuple[Any, ...] | None:
        """The row (header columns…, toml) of ``version`` (default: the latest)."""
        sql = f"SELECT {', '.join(('version', 'created_at', 'note', 'sha256', *self._VERSIONED[table]))}, toml FROM {table} "
        cur = (self._conn().execute(sql + "WHERE version=?", (version,)) if version is not None
               else self._conn().execute(sql + "ORDER BY version DESC LIMIT 1"))
        return cur.fetchone()

    def add_compensation(self, toml: str, note: str = "", rollback_of: int | None = None) -> CompensationVersion:
        """Keep an accepted compensation (the TOML as applied) as the next version; returns it."""
        version, created = self._add_version("compensations", toml, note, (rollback_of,))
        return CompensationVersion(version, created, note, text_sha256(toml), rollback_of)

    def compensation_history(self, limit: int = 100) -> list[CompensationVersion]:
        """Accepted compensations, newest first."""
        return [CompensationVersion(*row) for row in self._history("compensations", limit)]

    def compensation(self, version: int | None = None) -> tuple[CompensationVersion, str] | None:
        """(version, TOML) of ``version`` (default: the latest, the one in use); None when there is none."""
        row = self._version("compensations", version)
        return None if row is None else (CompensationVersion(*row[:-1]), row[-1])

    def add_bench_model(self, toml: str, note: str = "", analysis_id: str | None = None,
                        run_id: str | None = None) -> BenchModelVersion:
        """Keep the next version of the bench model (its whole discrepancy model TOML); returns it."""
        version, created = self._add_version("bench_models", toml, note, (analysis_id, run_id))
        return BenchModelVersion(version, created, note, text_sha256(toml), analysis_id, run_id)

    def bench_model_history(self, limit: int = 100) -> list[BenchModelVersion]:
        """Bench model versions, newest first."""
        return [BenchModelVersion(*row) for row in self._history("bench_models", limit)]

    def bench_model(self, version: int | None = None) -> tuple[BenchModelVersion, str] | None:
        """(version, TOML) of ``version`` (default: the latest, the one in use); None when there is none."""
        row = self._version("bench_models", version)
        return None if row is None else (BenchModelVersion(*row[:-1]), row[-1])

    # -- runs (reading) --------------------------------------------------------------------------------------
    def get_run(self, run_id: str) -> StoredRun | None:
        row = self._conn().execute(
            "SELECT id, created_at, started_at, finished_at, status, request, profile, results, error, "
            "config_snapshot, compensator_toml, channels, sample_count, compensation_version FROM runs WHERE id=?",
            (run_id,),
        ).fetchone()
        return None if row is None else _record(row)

    def list_runs(self, limit: int = 100, offset: int = 0) -> list[StoredRun]:
        rows = self._conn().execute(
            "SELECT id, created_at, started_at, finished_at, status, request, profile, results, error, "
            "NULL, NULL, channels, sample_count, compensation_version FROM runs ORDER BY created_at DESC, id DESC "
            "LIMIT ? OFFSET ?",
            (limit, offset),
        ).fetchall()
        return [_record(r) for r in rows]

    def count_by_status(self) -> dict[str, int]:
        counts = dict.fromkeys(RUN_STATUSES, 0)
        for status, n in self._conn().execute("SELECT status, COUNT(*) FROM runs GROUP BY status"):
            counts[status] = n
        return counts

    # -- samples ---------------------------------------------------------------------------------------------
    def append_samples(self, run_id: str, batches: Sequence[Mapping[str, np.ndarray]]) -> int:
        """Append column batches (each a mapping channel → array, the run's channels) in one transaction.

        Returns the number of samples written.
        """
        if not batches:
            return 0
        channels = self._channels(run_id)
        rows: list[tuple[int, bytes]] = []
        for cols in batches:
            try:
                block = np.stack([np.asarray(cols[c], dtype=_LE_F64) for c in channels])
            except KeyError as exc:
                raise StoreError(f"run {run_id}: batch lacks channel {exc.args[0]!r}") from None
            except ValueError:
                raise StoreError(f"run {run_id}: batch columns differ in length") from None
            if block.shape[1]:
                rows.append((block.shape[1], block.tobytes()))
        if not rows:
            return 0
        total = sum(n for n, _ in rows)
        with self._write_lock:
            conn = self._conn()
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
        row = self._conn().execute("SELECT channels FROM runs WHERE id=?", (run_id,)).fetchone()
        if row is None:
            raise StoreError(f"unknown run {run_id!r}")
        return tuple(json.loads(row[0]))

    def iter_columns(self, run_id: str, chunk_samples: int = 65_536) -> Iterator[dict[str, np.ndarray]]:
        """A run's samples in consecutive chunks of about ``chunk_samples`` (whole stored batches), as float64
        columns by channel name: for exports that stream. Each chunk is its own query, so the iterator may be
        advanced from different threads."""
        channels = self._channels(run_id)
        next_index = 0
        while True:
            rows = self._conn().execute(
                "SELECT batch_index, n_samples, data FROM sample_batches WHERE run_id=? AND batch_index >= ? "
                "ORDER BY batch_index LIMIT ?", (run_id, next_index, max(1, chunk_samples // 64)),
            ).fetchall()
            if not rows:
                return
            blocks = []
            for index, n, blob in rows:
                blocks.append(np.frombuffer(blob, dtype=_LE_F64).reshape(len(channels), n))
                next_index = index + 1
                if sum(b.shape[1] for b in blocks) >= chunk_samples:
                    break
            data = np.concatenate(blocks, axis=1)
            yield {name: data[i].astype(float, copy=True) for i, name in enumerate(channels)}

    def read_columns(self, run_id: str) -> dict[str, np.ndarray]:
        """All samples of a run as float64 columns by channel name (empty arrays when none were recorded)."""
        channels = self._channels(run_id)
        chunks = list(self.iter_columns(run_id))
        if not chunks:
            return {name: np.empty(0) for name in channels}
        return {name: np.concatenate([c[name] for c in chunks]) for name in channels}

    def read_samples(self, run_id: str) -> Samples:
        return samples_from_columns(self.read_columns(run_id))


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
    )

"""The run store on PostgreSQL: a plant's benches share one database (psycopg 3 and its connection pool).

Opening migrates the schema to the version this code knows (``schema_version``; concurrent starts serialise on an
advisory lock), then — when it starts a service (``recover=True``) — takes the bench's own advisory lock for
as long as the store is open, so a second service of the same bench is refused instead of interrupting the
first one's test, and marks the runs this bench left active as ``interrupted`` (never another bench's).

Samples go in bulk: one ``COPY … FROM STDIN (FORMAT BINARY)`` per commit of the recorder, one row per acquisition
batch (a channel-major little-endian float64 ``bytea``), in the same transaction as the run's sample count. A
committed batch survives a kill of the service (PostgreSQL's commit is durable: ``synchronous_commit`` on).

A plant's years of samples: ``sample_batches`` is partitioned by the run's creation time, one partition per UTC
month (``sample_batches_y2026m11``, made with the run that first needs it; ``sample_partitions`` lists them with
their bounds), so a run's batches are in one partition and a query for one run touches one. The retention policy
(:meth:`PostgresRunStore.retire_samples`, ``tcms store retire``) drops whole months older than a cutoff — a
``DROP TABLE``, no row-by-row delete, no bloat — and stamps those runs' ``samples_retired_at``: their records and
results stay, their samples answer 410 Gone.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import psycopg
from psycopg import sql
from psycopg.types.json import Jsonb
from psycopg_pool import ConnectionPool, PoolTimeout

from tcms_daq.identity import HEADLINES
from tcms_daq.store.base import (
    ACTIVE_STATUSES,
    BRIEF_KEYS,
    EXACT_TOTAL_UP_TO,
    INTERRUPTED_ERROR,
    RUN_STATUSES,
    VERSIONED,
    HeadlinePoint,
    HeadlineSeries,
    RunColumns,
    RunQuery,
    RunTotal,
    SamplesRetired,
    StoredRun,
    StoredSamples,
    StoreError,
    VersionedDocuments,
    brief_results,
    check_new_run,
    dumps,
    finite_number,
    pack_batches,
    status_update,
    test_series,
    text_sha256,
)
from tcms_daq.store.opening import redact_url
from tcms_daq.store.people import POSTGRES_MIGRATION as _PEOPLE_MIGRATION
from tcms_daq.store.people import POSTGRES_SETTINGS_MIGRATION as _SETTINGS_MIGRATION
from tcms_daq.store.people import BenchSettingsRecords

log = logging.getLogger(__name__)

# Each entry moves the schema one version up; applied in order, each in its own transaction. Never edit an
# applied entry: add the next one.
MIGRATIONS: tuple[str, ...] = (
    """
    CREATE TABLE runs (
        id text PRIMARY KEY,
        created_at double precision NOT NULL,
        started_at double precision,
        finished_at double precision,
        status text NOT NULL,
        request jsonb NOT NULL,
        profile jsonb,
        results jsonb,
        error text,
        config_snapshot jsonb,
        compensator_toml text,
        channels jsonb NOT NULL,
        sample_count bigint NOT NULL DEFAULT 0,
        compensation_version integer,
        bench_id text,
        bench_name text,
        reducer text,
        serial_number text,
        operator text,
        verdict text
    );
    CREATE INDEX runs_created ON runs (created_at DESC, id DESC);
    CREATE INDEX runs_bench ON runs (bench_id, created_at);
    CREATE INDEX runs_serial ON runs (lower(serial_number));
    CREATE INDEX runs_reducer ON runs (lower(reducer));
    CREATE INDEX runs_active ON runs (bench_id) WHERE status IN ('queued', 'running');
    CREATE TABLE compensations (
        version integer GENERATED ALWAYS AS IDENTITY PRIMARY KEY,
        created_at double precision NOT NULL,
        note text NOT NULL,
        sha256 text NOT NULL,
        toml text NOT NULL,
        bench_id text,
        rollback_of integer
    );
    CREATE TABLE bench_models (
        version integer GENERATED ALWAYS AS IDENTITY PRIMARY KEY,
        created_at double precision NOT NULL,
        note text NOT NULL,
        sha256 text NOT NULL,
        toml text NOT NULL,
        bench_id text,
        analysis_id text,
        run_id text
    );
    CREATE TABLE sample_batches (
        run_id text NOT NULL REFERENCES runs(id) ON DELETE CASCADE,
        batch_index integer NOT NULL,
        n_samples integer NOT NULL,
        data bytea NOT NULL,
        PRIMARY KEY (run_id, batch_index)
    );
    """,
    # 2: a plant's years: samples partitioned by month of the run's creation; runs whose samples a retention policy
    # retired; the headline results in columns (SPC reads them without the whole results); the fleet list's indexes
    """
    ALTER TABLE runs ADD COLUMN samples_retired_at double precision,
        ADD COLUMN rigidity_nm_per_arcmin double precision,
        ADD COLUMN lost_motion_arcsec double precision,
        ADD COLUMN backlash_arcsec double precision,
        ADD COLUMN test_series text;
    UPDATE runs SET
        rigidity_nm_per_arcmin = CASE WHEN jsonb_typeof(results->'rigidity_nm_per_arcmin') = 'number'
                                      THEN (results->>'rigidity_nm_per_arcmin')::double precision END,
        lost_motion_arcsec = CASE WHEN jsonb_typeof(results->'lost_motion_arcsec') = 'number'
                                  THEN (results->>'lost_motion_arcsec')::double precision END,
        backlash_arcsec = CASE WHEN jsonb_typeof(results->'backlash_arcsec') = 'number'
                               THEN (results->>'backlash_arcsec')::double precision END
        WHERE results IS NOT NULL;
    DROP INDEX runs_reducer;
    CREATE INDEX runs_reducer ON runs (lower(reducer), created_at DESC, id DESC);
    CREATE INDEX runs_bench_name ON runs (lower(bench_name), created_at DESC, id DESC);
    CREATE TABLE sample_partitions (
        name text PRIMARY KEY,
        from_s double precision NOT NULL,
        to_s double precision NOT NULL
    );
    ALTER TABLE sample_batches RENAME TO sample_batches_v1;
    CREATE TABLE sample_batches (
        run_id text NOT NULL REFERENCES runs(id) ON DELETE CASCADE,
        run_created_at double precision NOT NULL,
        batch_index integer NOT NULL,
        n_samples integer NOT NULL,
        data bytea NOT NULL,
        PRIMARY KEY (run_id, run_created_at, batch_index)
    ) PARTITION BY RANGE (run_created_at);
    -- the month partition holding a run created at t (UNIX s, UTC), made when missing; returns its name
    CREATE FUNCTION tcms_sample_partition(t double precision) RETURNS text LANGUAGE plpgsql AS $$
    DECLARE
        v_month timestamp := date_trunc('month', to_timestamp(t) AT TIME ZONE 'UTC');
        v_name text := 'sample_batches_' || to_char(v_month, '"y"YYYY"m"MM');
        v_from double precision := extract(epoch FROM v_month AT TIME ZONE 'UTC');
        v_to double precision := extract(epoch FROM (v_month + interval '1 month') AT TIME ZONE 'UTC');
    BEGIN
        IF EXISTS (SELECT 1 FROM sample_partitions p WHERE p.name = v_name) THEN
            RETURN v_name;
        END IF;
        PERFORM pg_advisory_xact_lock(2084896771);  -- one maker of partitions at a time
        IF NOT EXISTS (SELECT 1 FROM sample_partitions p WHERE p.name = v_name) THEN
            EXECUTE format('CREATE TABLE %I PARTITION OF sample_batches FOR VALUES FROM (%s) TO (%s)',
                           v_name, v_from, v_to);
            INSERT INTO sample_partitions (name, from_s, to_s) VALUES (v_name, v_from, v_to);
        END IF;
        RETURN v_name;
    END $$;
    SELECT tcms_sample_partition(created_at) FROM (SELECT DISTINCT created_at FROM runs
        WHERE id IN (SELECT DISTINCT run_id FROM sample_batches_v1)) AS with_samples;
    INSERT INTO sample_batches (run_id, run_created_at, batch_index, n_samples, data)
        SELECT b.run_id, r.created_at, b.batch_index, b.n_samples, b.data
        FROM sample_batches_v1 b JOIN runs r ON r.id = b.run_id;
    DROP TABLE sample_batches_v1;
    """,
    _PEOPLE_MIGRATION,  # users, API tokens, sessions, the append-only audit trail, saved plans
    # 4: a plant's year at the fleet page's pace. The list newest first and SPC read their indexes alone (index-only
    # scans: the filters' and the chart's columns are in the index), never the runs' wide rows; the text search's
    # trigram index comes with it when pg_trgm can be had (_text_search_index)
    """
    DROP INDEX runs_created;
    CREATE INDEX runs_created ON runs (created_at DESC, id DESC)
        INCLUDE (bench_id, bench_name, reducer, serial_number, operator, status, verdict);
    DROP INDEX runs_reducer;
    CREATE INDEX runs_reducer ON runs (lower(reducer), created_at DESC, id DESC)
        INCLUDE (reducer, status, verdict, bench_id, bench_name, serial_number, test_series, rigidity_nm_per_arcmin,
                 lost_motion_arcsec, backlash_arcsec);
    """,
    # 5: each run's brief results (base.brief_results: what the fleet list shows) stored beside its whole results when
    # they are written, so a page of the brief list reads a few hundred bytes a run instead of decompressing 15 kB;
    # runs written before keep NULL and are reduced when listed
    "ALTER TABLE runs ADD COLUMN results_brief jsonb",
    _SETTINGS_MIGRATION,  # 6: the admin's run-time settings of each bench
    # 7: the units' transmission-error models (the TE workflow's versions, as the bench models')
    """
    CREATE TABLE te_models (
        version integer GENERATED ALWAYS AS IDENTITY PRIMARY KEY,
        created_at double precision NOT NULL,
        note text NOT NULL,
        sha256 text NOT NULL,
        toml text NOT NULL,
        bench_id text,
        analysis_id text,
        run_id text
    );
    """,
)
#: the text search (``RunQuery.text``, ``ILIKE '%…%'`` on these columns) by trigrams: its own migration step
_TEXT_SEARCH_INDEX = (
    "CREATE INDEX runs_text ON runs USING gin ("
    + ", ".join(f"(COALESCE({c}, '')) gin_trgm_ops" for c in RunQuery.TEXT_COLUMNS) + ")")

_MIGRATION_LOCK = 0x7C45_0001  # advisory lock keys of this application (two int4 keys: class, object)
_BENCH_LOCK_CLASS = 0x7C45_0002
_RUN_COLUMNS = ("id, created_at, started_at, finished_at, status, request, profile, results, error, "
                "config_snapshot, compensator_toml, channels, sample_count, compensation_version, bench_id, "
                "bench_name, samples_retired_at")
_LIST_COLUMNS = _RUN_COLUMNS.replace("config_snapshot, compensator_toml", "NULL, NULL")
# the brief list: the brief results stored with the results (migration 5), or for runs written before, the results
# reduced in the database (base.brief_results) in one pass (their uncertainty table reduced on the way), so each
# run's TOASTed results are decompressed once; a page of runs moves and parses kilobytes
_BRIEF_KEYS_SQL = ", ".join(f"'{k}'" for k in BRIEF_KEYS)
_BRIEF_RESULTS = (
    "CASE WHEN results IS NULL THEN NULL ELSE COALESCE((SELECT jsonb_object_agg(key, CASE WHEN key = 'uncertainty' "
    "THEN COALESCE((SELECT jsonb_object_agg(u.k, u.v) FROM jsonb_each(value) AS u(k, v) WHERE u.k IN "
    f"({_BRIEF_KEYS_SQL})), '{{}}') ELSE value END) FROM jsonb_each(results) WHERE key IN ({_BRIEF_KEYS_SQL}, "
    "'verdict', 'passed') OR (key = 'uncertainty' AND jsonb_typeof(value) = 'object')), '{}') END")
_BRIEF_COLUMNS = _LIST_COLUMNS.replace("results", f"COALESCE(results_brief, {_BRIEF_RESULTS})", 1)


def _json_text(obj: Any) -> str:
    return dumps(obj) or "null"


def _jsonb(obj: Mapping[str, Any] | None) -> Jsonb | None:
    return None if obj is None else Jsonb(dict(obj), dumps=_json_text)


class PostgresRunStore(VersionedDocuments, StoredSamples, HeadlineSeries, BenchSettingsRecords):
    """The :class:`~tcms_daq.store.base.Store` on PostgreSQL; thread-safe (a connection per operation from the
    pool)."""

    def __init__(self, url: str, *, recover: bool = True, bench_id: str | None = None,
                 bench_name: str | None = None, pool_size: int = 4, connect_timeout_s: float = 10.0):
        self.url = url
        self.bench_id = bench_id
        self.bench_name = bench_name
        self._closed = False
        self._bench_lock: psycopg.Connection[Any] | None = None
        try:
            self._pool = ConnectionPool(url, min_size=1, max_size=max(1, pool_size), open=False,
                                        name=f"tcms-{bench_id or 'reader'}", timeout=connect_timeout_s,
                                        kwargs={"connect_timeout": max(1, round(connect_timeout_s))})
            self._pool.open(wait=True, timeout=connect_timeout_s)
        except (PoolTimeout, psycopg.Error) as exc:
            self._pool.close()
            raise StoreError(f"run store {self.describe()}: cannot connect ({_reason(exc)})") from None
        try:
            self._migrate()
            if recover and bench_id is not None:
                self._lock_bench(bench_id)
            self.recovered_run_ids: list[str] = self._mark_interrupted() if recover else []
        except BaseException:
            self.close()
            raise

    def describe(self) -> str:
        return redact_url(self.url)

    # -- life cycle ------------------------------------------------------------------------------------------
    def _migrate(self) -> None:
        with self._pool.connection() as conn:
            conn.execute("SELECT pg_advisory_xact_lock(%s::bigint)", (_MIGRATION_LOCK,))
            conn.execute("CREATE TABLE IF NOT EXISTS schema_version (version integer NOT NULL)")
            row = conn.execute("SELECT max(version) FROM schema_version").fetchone()
            current = int(row[0]) if row and row[0] is not None else 0
            if current > len(MIGRATIONS):
                raise StoreError(f"run store {self.describe()} has schema version {current}, newer than this "
                                 f"program's {len(MIGRATIONS)}: update TCMS-DAQ")
            for version in range(current + 1, len(MIGRATIONS) + 1):
                conn.execute(MIGRATIONS[version - 1])  # our own SQL, no parameters
                if version == 2:
                    _fill_test_series(conn)
                if version == 4:
                    _text_search_index(conn)
                conn.execute("INSERT INTO schema_version (version) VALUES (%s)", (version,))

    @property
    def schema_version(self) -> int:
        with self._pool.connection() as conn:
            row = conn.execute("SELECT max(version) FROM schema_version").fetchone()
        return int(row[0]) if row and row[0] is not None else 0

    def _lock_bench(self, bench_id: str) -> None:
        """Hold this bench's advisory lock while the store is open (released by PostgreSQL when the process
        dies): a second service of the same bench on this database is refused."""
        conn = psycopg.connect(self.url, autocommit=True, connect_timeout=10)
        got = conn.execute("SELECT pg_try_advisory_lock(%s::int4, hashtext(%s))", (_BENCH_LOCK_CLASS, bench_id)).fetchone()
        if not (got and got[0]):
            conn.close()
            raise StoreError(f"bench {bench_id!r} is already served by another service on {self.describe()}; "
                             "give each bench its own [bench] id")
        self._bench_lock = conn

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        if self._bench_lock is not None:
            self._bench_lock.close()
        self._pool.close()

    def __enter__(self) -> PostgresRunStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _connection(self) -> Any:
        if self._closed:
            raise StoreError(f"run store {self.describe()} is closed")
        return self._pool.connection()

    def _own(self) -> tuple[str, tuple[Any, ...]]:
        """SQL condition (and parameters) selecting this bench's rows (every row for a store without a bench)."""
        if self.bench_id is None:
            return "TRUE", ()
        return "bench_id = %s", (self.bench_id,)

    # -- runs ------------------------------------------------------------------------------------------------
    def _mark_interrupted(self) -> list[str]:
        if self.bench_id is None:
            return []  # a store without a bench never decides that another service is dead
        with self._connection() as conn:
            rows = conn.execute(
                "UPDATE runs SET status = 'interrupted', finished_at = COALESCE(finished_at, %s), "
                "error = COALESCE(error, %s) WHERE status = ANY(%s) AND bench_id = %s RETURNING id, created_at",
                (time.time(), INTERRUPTED_ERROR, list(ACTIVE_STATUSES), self.bench_id),
            ).fetchall()
        return [r[0] for r in sorted(rows, key=lambda r: r[1])]

    def create_run(self, run_id: str, request: Mapping[str, Any], channels: Sequence[str], *,
                   profile: Mapping[str, Any] | None = None, config_snapshot: Mapping[str, Any] | None = None,
                   compensator_toml: str | None = None, compensation_version: int | None = None,
                   status: str = "queued") -> StoredRun:
        check_new_run(run_id, channels, status)
        cols = RunColumns.of(request)
        created = time.time()
        try:
            with self._connection() as conn:
                conn.execute(
                    "INSERT INTO runs (id, created_at, status, request, profile, config_snapshot, compensator_toml, "
                    "channels, compensation_version, bench_id, bench_name, reducer, serial_number, operator, "
                    "test_series) VALUES (%s, %s, %s, %s, %s, %s, %s, %s, %s, %s, %s, %s, %s, %s, %s)",
                    (run_id, created, status, _jsonb(request), _jsonb(profile), _jsonb(config_snapshot),
                     compensator_toml, Jsonb(list(channels)), compensation_version, self.bench_id,
                     self.bench_name, cols.reducer, cols.serial_number, cols.operator, test_series(request, profile)),
                )
                conn.execute("SELECT tcms_sample_partition(%s)", (created,))  # its month's, before any sample
        except psycopg.errors.UniqueViolation:
            raise StoreError(f"run {run_id} already exists") from None
        return self.get_run(run_id)  # type: ignore[return-value]

    def set_status(self, run_id: str, status: str, *, error: str | None = None,
                   results: Mapping[str, Any] | None = None) -> None:
        """Move a run to ``status`` (:func:`~tcms_daq.store.base.status_update`)."""
        sets, params = status_update(status, error=error, results=results, encode_results=_jsonb, placeholder="%s")
        if results is not None:  # the headline results also in their columns (SPC), the brief ones for the list
            sets += "".join(f", {h.key} = %s" for h in HEADLINES) + ", results_brief = %s"
            params += [finite_number(results.get(h.key)) for h in HEADLINES] + [_jsonb(brief_results(results))]
        params.append(run_id)
        with self._connection() as conn:
            cur = conn.execute(f"UPDATE runs SET {sets} WHERE id = %s", params)
            if cur.rowcount == 0:
                raise StoreError(f"unknown run {run_id!r}")

    def get_run(self, run_id: str) -> StoredRun | None:
        with self._connection() as conn:
            row = conn.execute(f"SELECT {_RUN_COLUMNS} FROM runs WHERE id = %s", (run_id,)).fetchone()
        return None if row is None else _record(row)

    def list_runs(self, limit: int = 100, offset: int = 0, query: RunQuery | None = None, *,
                  brief: bool = False) -> list[StoredRun]:
        """Runs of every bench matching ``query``, newest first (without their config snapshot and TOML; ``brief``:
        results reduced to :func:`~tcms_daq.store.base.brief_results` in the database)."""
        where, params = (query or RunQuery()).where("%s", "ILIKE")
        with self._connection() as conn:
            # the page's ids first, then its columns: the rows an OFFSET skips are never read or reduced
            rows = conn.execute(
                f"SELECT {_BRIEF_COLUMNS if brief else _LIST_COLUMNS} FROM runs JOIN (SELECT id AS page_id FROM runs "
                f"{where} ORDER BY created_at DESC, id DESC LIMIT %s OFFSET %s) AS page ON runs.id = page.page_id "
                "ORDER BY created_at DESC, id DESC", (*params, limit, offset)).fetchall()
        return [_record(r) for r in rows]

    def count_runs(self, query: RunQuery | None = None) -> int:
        where, params = (query or RunQuery()).where("%s", "ILIKE")
        with self._connection() as conn:
            row = conn.execute(f"SELECT count(*) FROM runs {where}", params).fetchone()
        return int(row[0]) if row else 0

    def total_runs(self, query: RunQuery | None = None, exact_up_to: int = EXACT_TOTAL_UP_TO) -> RunTotal:
        """Exact up to ``exact_up_to`` matching runs (counted from the index, stopping at one more); past it the
        planner's estimate of the matching rows, never below what was counted (a plant's year is 500 000 runs:
        counting them exactly would cost more than the page)."""
        where, params = (query or RunQuery()).where("%s", "ILIKE")
        with self._connection() as conn:
            row = conn.execute(f"SELECT count(*) FROM (SELECT 1 FROM runs {where} LIMIT %s) AS counted",
                               (*params, exact_up_to + 1)).fetchone()
            counted = int(row[0]) if row else 0
            if counted <= exact_up_to:
                return RunTotal(counted)
            plan = conn.execute(f"EXPLAIN (FORMAT JSON) SELECT 1 FROM runs {where}", params).fetchone()
        estimate = int(plan[0][0]["Plan"]["Plan Rows"]) if plan else 0
        return RunTotal(max(estimate, counted), exact=False)

    def headline_points(self, quantity: str, query: RunQuery, limit: int) -> list[HeadlinePoint]:
        """:meth:`HeadlineSeries.headline_points` from the headline columns: the runs' whole results are not read."""
        if quantity not in {h.key for h in HEADLINES}:
            raise StoreError(f"unknown headline result {quantity!r}")
        where, params = query.where("%s", "ILIKE")
        with self._connection() as conn:
            rows = conn.execute(
                f"SELECT * FROM (SELECT id, created_at, bench_id, serial_number, test_series, {quantity} FROM runs "
                f"{where} ORDER BY created_at DESC, id DESC LIMIT %s) AS newest "
                f"WHERE {quantity} IS NOT NULL ORDER BY created_at, id", (*params, limit)).fetchall()
        return [HeadlinePoint(r[0], r[1], r[2], r[3], r[4] or "single", float(r[5])) for r in rows]

    def count_by_status(self) -> dict[str, int]:
        """Runs of this bench by status (every bench's for a store without one)."""
        counts = dict.fromkeys(RUN_STATUSES, 0)
        own, own_params = self._own()
        with self._connection() as conn:
            rows = conn.execute(f"SELECT status, count(*) FROM runs WHERE {own} GROUP BY status", own_params)
            for status, n in rows.fetchall():
                counts[status] = int(n)
        return counts

    # -- versioned TOML documents of this bench ---------------------------------------------------------------
    def _add_version(self, table: str, toml: str, note: str, provenance: Sequence[Any]) -> tuple[int, float]:
        columns = ("created_at", "note", "sha256", "toml", "bench_id", *VERSIONED[table])
        created = time.time()
        with self._connection() as conn:
            row = conn.execute(
                f"INSERT INTO {table} ({', '.join(columns)}) VALUES ({', '.join(['%s'] * len(columns))}) "
                "RETURNING version", (created, note, text_sha256(toml), toml, self.bench_id, *provenance)).fetchone()
        assert row is not None
        return int(row[0]), created

    def _history(self, table: str, limit: int) -> list[tuple[Any, ...]]:
        columns = ("version", "created_at", "note", "sha256", *VERSIONED[table])
        own, own_params = self._own()
        with self._connection() as conn:
            return [tuple(r) for r in conn.execute(
                f"SELECT {', '.join(columns)} FROM {table} WHERE {own} ORDER BY version DESC LIMIT %s",
                (*own_params, limit)).fetchall()]

    def _version(self, table: str, version: int | None) -> tuple[Any, ...] | None:
        own, own_params = self._own()
        sql = (f"SELECT {', '.join(('version', 'created_at', 'note', 'sha256', *VERSIONED[table]))}, toml "
               f"FROM {table} WHERE {own} ")
        with self._connection() as conn:
            if version is not None:
                row = conn.execute(sql + "AND version = %s", (*own_params, version)).fetchone()
            else:
                row = conn.execute(sql + "ORDER BY version DESC LIMIT 1", own_params).fetchone()
        return None if row is None else tuple(row)

    # -- people (users, audit, plans: tcms_daq.store.people) ------------------------------------------------
    def _people_query(self, sql: str, params: Sequence[Any] = ()) -> list[tuple[Any, ...]]:
        with self._connection() as conn:
            return [tuple(r) for r in conn.execute(sql.replace("?", "%s"), params).fetchall()]

    def _people_execute(self, sql: str, params: Sequence[Any] = ()) -> int:
        try:
            with self._connection() as conn:
                return int(conn.execute(sql.replace("?", "%s"), params).rowcount)
        except psycopg.Error as exc:
            raise StoreError(f"refused by the run store: {_reason(exc)}") from None

    def _json_param(self, obj: Mapping[str, Any]) -> Any:
        return _jsonb(obj)

    # -- samples ----------------------------------------------------------------------------------------------
    def _sample_key(self, run_id: str, conn: Any) -> tuple[tuple[str, ...], float]:
        """(channels, created_at) of a run: its channel names and its samples' partition key. StoreError for an
        unknown run, SamplesRetired for a run whose samples a retention policy dropped."""
        row = conn.execute("SELECT channels, created_at, samples_retired_at FROM runs WHERE id = %s",
                           (run_id,)).fetchone()
        if row is None:
            raise StoreError(f"unknown run {run_id!r}")
        if row[2] is not None:
            raise SamplesRetired.of(run_id, row[2])
        return tuple(row[0]), float(row[1])

    def _channels(self, run_id: str) -> tuple[str, ...]:
        with self._connection() as conn:
            return self._sample_key(run_id, conn)[0]

    def append_samples(self, run_id: str, batches: Sequence[Mapping[str, np.ndarray]]) -> int:
        """Append column batches in one transaction: one binary COPY, a row per batch. Returns samples written."""
        if not batches:
            return 0
        with self._connection() as conn:
            channels, created = self._sample_key(run_id, conn)
            rows = pack_batches(run_id, channels, batches)
            if not rows:
                return 0
            total = sum(n for n, _ in rows)
            # the run's row lock orders concurrent appends to one run; other runs are not held up
            conn.execute("SELECT 1 FROM runs WHERE id = %s FOR UPDATE", (run_id,))
            start_row = conn.execute(
                "SELECT COALESCE(max(batch_index) + 1, 0) FROM sample_batches WHERE run_id = %s AND run_created_at = %s",
                (run_id, created)).fetchone()
            start = int(start_row[0]) if start_row else 0
            with conn.cursor() as cur, cur.copy("COPY sample_batches (run_id, run_created_at, batch_index, n_samples, "
                                                "data) FROM STDIN (FORMAT BINARY)") as copy:
                copy.set_types(["text", "float8", "int4", "int4", "bytea"])
                for i, (n, blob) in enumerate(rows):
                    copy.write_row((run_id, created, start + i, n, blob))
            conn.execute("UPDATE runs SET sample_count = sample_count + %s WHERE id = %s", (total, run_id))
        return total

    def _batch_rows(self, run_id: str, from_index: int, limit: int) -> list[tuple[Any, ...]]:
        with self._connection() as conn:
            # the run's creation time names its partition: the planner reads one month, not every month
            return conn.execute(
                "SELECT batch_index, n_samples, data FROM sample_batches WHERE run_id = %s AND run_created_at = "
                "(SELECT created_at FROM runs WHERE id = %s) AND batch_index >= %s ORDER BY batch_index LIMIT %s",
                (run_id, run_id, from_index, limit)).fetchall()

    # -- retention: whole months of samples ----------------------------------------------------------------------
    def sample_partitions(self) -> list[SamplePartition]:
        """The month partitions of the samples, oldest first, with their size and how many runs have samples in
        each (every bench's)."""
        with self._connection() as conn:
            rows = conn.execute(
                "SELECT p.name, p.from_s, p.to_s, pg_total_relation_size(p.name::regclass), "
                "(SELECT count(*) FROM runs r WHERE r.created_at >= p.from_s AND r.created_at < p.to_s "
                "AND r.sample_count > 0) FROM sample_partitions p ORDER BY p.from_s").fetchall()
        return [SamplePartition(name, from_s, to_s, int(size), int(runs)) for name, from_s, to_s, size, runs in rows]

    def retire_samples(self, before_s: float, *, dry_run: bool = False) -> list[SamplePartition]:
        """The retention policy: drop every month partition that ends at or before ``before_s`` (UNIX s) and stamp
        its runs' ``samples_retired_at`` (records and results stay). A month holding an active run is kept.
        Returns the partitions dropped (or, with ``dry_run``, those that would be)."""
        retired: list[SamplePartition] = []
        for part in self.sample_partitions():
            if part.to_s > before_s:
                break
            with self._connection() as conn:
                active = conn.execute(
                    "SELECT count(*) FROM runs WHERE created_at >= %s AND created_at < %s AND status = ANY(%s)",
                    (part.from_s, part.to_s, list(ACTIVE_STATUSES))).fetchone()
                if active and active[0]:
                    continue
                if dry_run:
                    retired.append(part)
                    continue
                conn.execute(
                    "UPDATE runs SET samples_retired_at = %s WHERE created_at >= %s AND created_at < %s "
                    "AND samples_retired_at IS NULL AND sample_count > 0", (time.time(), part.from_s, part.to_s))
                conn.execute(sql.SQL("DROP TABLE {}").format(sql.Identifier(part.name)))
                conn.execute("DELETE FROM sample_partitions WHERE name = %s", (part.name,))
            retired.append(part)
        return retired


@dataclass(frozen=True)
class SamplePartition:
    """One month of samples: the partition's name, its bounds (UNIX s, UTC, [from, to)), its size on disk
    (bytes, with its index and TOAST) and the runs with samples in it."""

    name: str
    from_s: float
    to_s: float
    size_bytes: int
    runs: int


def _fill_test_series(conn: Any) -> None:
    """Migration 2's Python part: the test-method series of the runs stored before it (from request and profile)."""
    rows = conn.execute("SELECT id, request, profile FROM runs WHERE test_series IS NULL").fetchall()
    with conn.cursor() as cur:
        cur.executemany("UPDATE runs SET test_series = %s WHERE id = %s",
                        [(test_series(request or {}, profile), run_id) for run_id, request, profile in rows])


def _text_search_index(conn: Any) -> None:
    """Migration 4's trigram index for the text search, when the pg_trgm extension is there or can be made (it is
    trusted since PostgreSQL 13: a database owner may create it); without it the search is right, only slower."""
    try:
        with conn.transaction():  # a savepoint: a refused extension leaves the migration's transaction usable
            conn.execute("CREATE EXTENSION IF NOT EXISTS pg_trgm")
    except psycopg.Error as exc:
        log.warning("run store: no pg_trgm (%s): the text search of the runs goes without its index", _reason(exc))
        return
    conn.execute(_TEXT_SEARCH_INDEX)


def _reason(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return text[0] if text else type(exc).__name__


def _record(row: Sequence[Any]) -> StoredRun:
    return StoredRun(
        id=row[0], created_at=row[1], started_at=row[2], finished_at=row[3], status=row[4],
        request=row[5] or {}, profile=row[6], results=row[7], error=row[8], config_snapshot=row[9],
        compensator_toml=row[10], channels=tuple(row[11]), sample_count=int(row[12]),
        compensation_version=row[13], bench_id=row[14], bench_name=row[15], samples_retired_at=row[16],
    )

"""What every run store offers (:class:`Store`, a typing Protocol) and what its backends share: the records they
return, the query of ``GET /api/tests`` (:class:`RunQuery`) and the packing of sample batches.

Two backends implement it: SQLite (:mod:`tcms_daq.store.sqlite_store`, one file per bench, the embedded default)
and PostgreSQL (:mod:`tcms_daq.store.postgres_store`, a plant's benches sharing one database). A store is opened
for one bench (``bench_id``/``bench_name``): every run it creates records that bench; versioned documents
(compensations, bench models) are that bench's; when it starts a service it marks only that bench's runs left
active as ``interrupted``. Reads of runs see every bench.

Samples are kept as one channel-major little-endian float64 blob per batch, the run's channel names on its record.
"""

from __future__ import annotations

import hashlib
import json
import math
import re
import time
import uuid
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar, Protocol

import numpy as np

from tcms_daq.analysis.evaluation import DECISIONS
from tcms_daq.errors import TcmsError
from tcms_daq.identity import (
    HEADLINES,
    decision,
    headline_results,
    method_headlines,
    run_identity,
    test_method,
)
from tcms_daq.runstate import STORED, STORED_ACTIVE, STORED_FINAL
from tcms_daq.samples import Samples, samples_from_columns

if TYPE_CHECKING:  # people.py imports this module
    from tcms_daq.store.people import AuditEntry, AuditQuery, SavedPlan, User

RUN_STATUSES: tuple[str, ...] = STORED  # tcms_daq.runstate.RunState: one vocabulary
ACTIVE_STATUSES: tuple[str, ...] = STORED_ACTIVE
FINAL_STATUSES: tuple[str, ...] = STORED_FINAL
VERDICTS: tuple[str, ...] = DECISIONS

LE_F64 = np.dtype("<f8")
INTERRUPTED_ERROR = "the service stopped while this run was active"
#: a bench id as configs write it ([bench] id): letters, digits, '.', '_' and '-'
BENCH_ID = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,63}$")


class StoreError(TcmsError):
    """The run store cannot do what was asked (unknown run, bad channel set, closed store, unreachable database)."""


class SamplesRetired(StoreError):
    """The run's samples were dropped by the store's retention policy (its record and results remain): 410 Gone."""

    @classmethod
    def of(cls, run_id: str, retired_at: float) -> SamplesRetired:
        return cls(f"the samples of run {run_id} were retired on {iso(retired_at)} by the store's retention "
                   "policy (its results remain: GET /api/tests/{id})")


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
    bench_id: str | None = None  # the bench that ran it ([bench] id of its config; None: before fleets)
    bench_name: str | None = None
    compensation_sha256: str | None = None  # of compensator_toml (kept when the listing leaves the TOML out)
    samples_retired_at: float | None = None  # when a retention policy dropped its samples (None: they are kept)

    def require_samples(self) -> None:
        """SamplesRetired when a retention policy dropped this run's samples."""
        if self.samples_retired_at is not None:
            raise SamplesRetired.of(self.id, self.samples_retired_at)

    @property
    def verdict(self) -> str | None:
        return decision(self.results)

    def summary(self) -> dict[str, Any]:
        """The JSON view used by the REST API (everything but the large snapshot fields)."""
        sha = self.compensation_sha256 or (None if self.compensator_toml is None else text_sha256(self.compensator_toml))
        return {
            "id": self.id,
            "status": self.status,
            "created_at": iso(self.created_at),
            "started_at": iso(self.started_at),
            "finished_at": iso(self.finished_at),
            "bench_id": self.bench_id,
            "bench_name": self.bench_name,
            "request": self.request,
            "results": self.results,
            "verdict": self.verdict,
            "headline": {key: entry["text"] for key, entry in headline_results(self.results).items()},
            "error": self.error,
            "sample_count": self.sample_count,
            "channels": list(self.channels),
            "compensation_version": self.compensation_version,
            "compensation_sha256": sha,
        }

    def identity(self) -> dict[str, Any]:
        """The test's identity and headline results (:func:`tcms_daq.identity.run_identity`)."""
        summary = self.summary()
        return run_identity(run_id=self.id, request=self.request, profile=self.profile, results=self.results,
                            bench_id=self.bench_id, bench_name=self.bench_name, status=self.status,
                            started_at_iso=summary["started_at"],
                            compensation_version=self.compensation_version,
                            compensation_sha256=summary["compensation_sha256"],
                            config_snapshot=self.config_snapshot)


#: what the brief view of a run's results keeps: its headline results, their uncertainty entries and the verdict
BRIEF_KEYS: tuple[str, ...] = tuple(h.key for h in HEADLINES)


def brief_results(results: Mapping[str, Any] | None) -> dict[str, Any] | None:
    """A run's results reduced to what a list shows: the headline results (value, their ``uncertainty`` entries),
    the verdict and ``passed``; None for none."""
    if results is None:
        return None
    keys = (*BRIEF_KEYS, *(h.key for h in method_headlines(results) if h.key not in BRIEF_KEYS))
    out = {k: results[k] for k in (*keys, "verdict", "passed", "method") if k in results}
    table = results.get("uncertainty")
    if isinstance(table, Mapping):
        out["uncertainty"] = {k: table[k] for k in keys if k in table}
    return out


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
        return {"version": self.version, "created_at": iso(self.created_at), "note": self.note,
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
        return {"version": self.version, "created_at": iso(self.created_at), "note": self.note,
                "sha256": self.sha256, "analysis_id": self.analysis_id, "run_id": self.run_id}


#: the versioned TOML documents: table -> its provenance columns (besides version, created_at, note, sha256, toml)
VERSIONED: dict[str, tuple[str, ...]] = {"compensations": ("rollback_of",), "bench_models": ("analysis_id", "run_id"),
                                         "te_models": ("analysis_id", "run_id")}


def iso(t: float | None) -> str | None:
    return None if t is None else datetime.fromtimestamp(t, UTC).isoformat(timespec="milliseconds")


def iso_many(times_s: Sequence[float]) -> list[str]:
    """:func:`iso` of many finite times (UNIX s) at once, character for character (an SPC chart's 10 000 runs):
    the microseconds rounded half to even from the fraction as ``datetime.fromtimestamp`` rounds them, then cut to
    milliseconds."""
    t = np.asarray(times_s, dtype=float)
    if t.size == 0:
        return []
    if not np.isfinite(t).all():
        raise ValueError("iso_many: every time must be finite")
    fraction, whole = np.modf(t)
    micro = np.round(fraction * 1e6)  # half to even, as datetime's ROUND_HALF_EVEN
    whole = whole + np.floor_divide(micro, 1e6)  # a fraction that rounds to 1 s (or below 0 for times before 1970)
    micro = np.mod(micro, 1e6)
    seconds = np.datetime_as_string(whole.astype("datetime64[s]"), unit="s")
    millis = (micro // 1000).astype(np.int64)
    return [f"{s}.{ms:03d}+00:00" for s, ms in zip(seconds.tolist(), millis.tolist(), strict=True)]


def new_run_id() -> str:
    """A time-sortable, human-readable run id: ``20261121-153012-1a2b3c``."""
    return f"{datetime.now(UTC):%Y%m%d-%H%M%S}-{uuid.uuid4().hex[:6]}"


def dumps(obj: Any) -> str | None:
    return None if obj is None else json.dumps(obj, allow_nan=False, default=_json_default)


def _json_default(obj: Any) -> Any:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


# -- the query of GET /api/tests -----------------------------------------------------------------------------
def check_time_window(since: float | None, until: float | None) -> None:
    """Raise StoreError unless ``since`` and ``until`` (epoch s, None: open) are finite and in order."""
    for name, value in (("since", since), ("until", until)):
        if value is not None and not math.isfinite(value):
            raise StoreError(f"{name} must be a finite time")
    if since is not None and until is not None and since > until:
        raise StoreError(f"since ({iso(since)}) is after until ({iso(until)})")


@dataclass(frozen=True)
class RunQuery:
    """Which runs to list. Every field narrows the list; None leaves it open. ``bench`` matches a bench's id or
    its name; ``serial`` and ``reducer`` match exactly (case-insensitive); ``text`` is a substring of the run id,
    serial number, reducer, operator or bench; ``since``/``until`` bound the creation time (UNIX seconds,
    inclusive; ``until`` to the millisecond, as the API shows times)."""

    #: the columns ``text`` searches (PostgreSQL's trigram index is made on the same expressions)
    TEXT_COLUMNS: ClassVar[tuple[str, ...]] = ("id", "serial_number", "reducer", "operator", "bench_id", "bench_name")

    bench: str | None = None
    reducer: str | None = None
    serial: str | None = None
    status: str | None = None
    verdict: str | None = None
    text: str | None = None
    since: float | None = None
    until: float | None = None

    def __post_init__(self) -> None:
        if self.status is not None and self.status not in RUN_STATUSES:
            raise StoreError(f"unknown status {self.status!r} (known: {', '.join(RUN_STATUSES)})")
        if self.verdict is not None and self.verdict not in VERDICTS:
            raise StoreError(f"unknown verdict {self.verdict!r} (known: {', '.join(VERDICTS)})")
        check_time_window(self.since, self.until)

    def where(self, placeholder: str, like: str) -> tuple[str, list[Any]]:
        """(``WHERE …`` or ``""``, parameters) for a backend's placeholder (``?``/``%s``) and its
        case-insensitive LIKE operator."""
        clauses: list[str] = []
        params: list[Any] = []
        p = placeholder

        if self.bench is not None:
            clauses.append(f"(bench_id = {p} OR lower(bench_name) = lower({p}))")
            params += [self.bench, self.bench]
        for column, value in (("reducer", self.reducer), ("serial_number", self.serial)):
            if value is not None:
                clauses.append(f"lower({column}) = lower({p})")
                params.append(value)
        for column, value in (("status", self.status), ("verdict", self.verdict)):
            if value is not None:
                clauses.append(f"{column} = {p}")
                params.append(value)
        if self.since is not None:
            clauses.append(f"created_at >= {p}")
            params.append(self.since)
        if self.until is not None:
            clauses.append(f"created_at < {p}")  # the millisecond ``until`` names is in (times show ms)
            params.append(self.until + 0.001)
        if self.text:
            pattern = "%" + self.text.replace("\\", "\\\\").replace("%", "\\%").replace("_", "\\_") + "%"
            columns = self.TEXT_COLUMNS
            clauses.append("(" + " OR ".join(f"COALESCE({c}, '') {like} {p} ESCAPE '\\'" for c in columns) + ")")
            params += [pattern] * len(columns)
        return ("WHERE " + " AND ".join(clauses)) if clauses else "", params


#: up to this many matching runs (ten pages of the fleet page) the list's total is counted; past it PostgreSQL gives
#: its planner's estimate, and the response says so: on a plant's year (500 000 runs) counting a bench's 25 000
#: runs read 200 000 index entries, more than the page itself
EXACT_TOTAL_UP_TO = 1_000


@dataclass(frozen=True)
class RunTotal:
    """How many runs match a query: ``count`` exact, or (``exact`` False) an estimate, made only once more than
    the counting limit matched and never below what was counted."""

    count: int
    exact: bool = True


@dataclass(frozen=True)
class RunColumns:
    """The searchable columns a run record keeps beside its JSON request and results."""

    reducer: str | None = None
    serial_number: str | None = None
    operator: str | None = None

    @classmethod
    def of(cls, request: Mapping[str, Any]) -> RunColumns:
        def text(key: str) -> str | None:
            value = request.get(key)
            return value if isinstance(value, str) else None

        return cls(text("reducer"), text("serial_number"), text("operator"))


# -- samples ----------------------------------------------------------------------------------------------------
def pack_batches(run_id: str, channels: Sequence[str],
                 batches: Sequence[Mapping[str, np.ndarray]]) -> list[tuple[int, bytes]]:
    """Each non-empty batch as (n_samples, channel-major little-endian float64 bytes); StoreError when a batch
    lacks a channel or its columns differ in length."""
    rows: list[tuple[int, bytes]] = []
    for cols in batches:
        try:
            block = np.stack([np.asarray(cols[c], dtype=LE_F64) for c in channels])
        except KeyError as exc:
            raise StoreError(f"run {run_id}: batch lacks channel {exc.args[0]!r}") from None
        except ValueError:
            raise StoreError(f"run {run_id}: batch columns differ in length") from None
        if block.shape[1]:
            rows.append((block.shape[1], block.tobytes()))
    return rows


def unpack_blocks(channels: Sequence[str], blobs: Sequence[tuple[int, bytes]]) -> dict[str, np.ndarray]:
    """Stored (n_samples, blob) batches back to float64 columns by channel name."""
    blocks = [np.frombuffer(blob, dtype=LE_F64).reshape(len(channels), n) for n, blob in blobs]
    data = np.concatenate(blocks, axis=1)
    return {name: data[i].astype(float, copy=True) for i, name in enumerate(channels)}


def check_new_run(run_id: str, channels: Sequence[str], status: str) -> None:
    if status not in RUN_STATUSES:
        raise StoreError(f"unknown run status {status!r}")
    if not channels or len(set(channels)) != len(channels):
        raise StoreError(f"run {run_id}: channel names must be unique and non-empty, got {list(channels)}")


def status_update(status: str, *, error: str | None, results: Mapping[str, Any] | None,
                  encode_results: Callable[[Mapping[str, Any]], Any], placeholder: str) -> tuple[str, list[Any]]:
    """The ``SET`` clause and its parameters that move a run to ``status`` (both backends; ``placeholder`` is the
    driver's, ``?`` or ``%s``): ``running`` stamps the start time once, a final status the finish time; results
    are stored with their decision. Raises StoreError for an unknown status."""
    if status not in RUN_STATUSES:
        raise StoreError(f"unknown run status {status!r}")
    now = time.time()
    p = placeholder
    sets: list[str] = [f"status = {p}"]
    params: list[Any] = [status]
    if status == "running":
        sets.append(f"started_at = COALESCE(started_at, {p})")
        params.append(now)
    if status in FINAL_STATUSES:
        sets.append(f"finished_at = {p}")
        params.append(now)
    if error is not None:
        sets.append(f"error = {p}")
        params.append(error)
    if results is not None:
        sets += [f"results = {p}", f"verdict = {p}"]
        params += [encode_results(results), decision(results)]
    return ", ".join(sets), params


class StoredSamples:
    """Reading a run's samples back, over a backend's two primitives: ``_channels(run_id)`` (the run's channel
    names; StoreError for an unknown run) and ``_batch_rows(run_id, from_index, limit)`` (rows of (batch_index,
    n_samples, data) from ``from_index`` on, in order). Both backends inherit it."""

    def _channels(self, run_id: str) -> tuple[str, ...]:
        raise NotImplementedError

    def _batch_rows(self, run_id: str, from_index: int, limit: int) -> list[tuple[Any, ...]]:
        raise NotImplementedError

    def iter_columns(self, run_id: str, chunk_samples: int = 65_536) -> Iterator[dict[str, np.ndarray]]:
        """A run's samples in consecutive chunks of about ``chunk_samples`` (whole stored batches), as float64
        columns by channel name: for exports that stream. Each chunk is its own query, so the iterator may be
        advanced from different threads."""
        channels = self._channels(run_id)
        next_index = 0
        while True:
            rows = self._batch_rows(run_id, next_index, max(1, chunk_samples // 64))
            if not rows:
                return
            blobs: list[tuple[int, bytes]] = []
            collected = 0
            for index, n, blob in rows:
                blobs.append((n, bytes(blob)))
                collected += n
                next_index = index + 1
                if collected >= chunk_samples:
                    break
            yield unpack_blocks(channels, blobs)

    def read_columns(self, run_id: str) -> dict[str, np.ndarray]:
        """All samples of a run as float64 columns by channel name (empty arrays when none were recorded)."""
        channels = self._channels(run_id)
        chunks = list(self.iter_columns(run_id))
        if not chunks:
            return {name: np.empty(0) for name in channels}
        return {name: np.concatenate([c[name] for c in chunks]) for name in channels}

    def read_samples(self, run_id: str) -> Samples:
        return samples_from_columns(self.read_columns(run_id))


@dataclass(frozen=True)
class HeadlinePoint:
    """One run's value of one headline result (a point of an SPC series), with what places it: the run's id,
    creation time (UNIX s), bench, the unit's serial number and the series of its test method
    (:func:`tcms_daq.identity.test_method`)."""

    id: str
    created_at: float
    bench_id: str | None
    serial_number: str | None
    series: str
    value: float


def finite_number(value: Any) -> float | None:
    """``value`` as a float when it is a finite JSON number (not a bool), else None."""
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        return None
    return float(value)


class HeadlineSeries:
    """A headline result across runs (SPC), over ``list_runs``; a backend with the headline results in columns
    (PostgreSQL) answers without reading the runs' whole results."""

    def list_runs(self, limit: int = 100, offset: int = 0, query: RunQuery | None = None, *,
                  brief: bool = False) -> list[StoredRun]:
        raise NotImplementedError

    def headline_points(self, quantity: str, query: RunQuery, limit: int) -> list[HeadlinePoint]:
        """Of the newest ``limit`` runs matching ``query``, those with a finite ``quantity`` (a key of
        :data:`tcms_daq.identity.HEADLINES`), oldest first."""
        points = []
        for run in reversed(self.list_runs(limit, 0, query)):
            value = finite_number((run.results or {}).get(quantity))
            if value is not None:
                points.append(HeadlinePoint(run.id, run.created_at, run.bench_id, RunColumns.of(run.request).serial_number,
                                            test_series(run.request, run.profile), value))
        return points


def test_series(request: Mapping[str, Any], profile: Mapping[str, Any] | None) -> str:
    """The SPC series of a run's test method (``single``, ``positions-4`` …)."""
    return str(test_method(request, profile)["series"])


class VersionedDocuments:
    """The versioned TOML documents of a bench — compensations and bench models — over a backend's three
    primitives: ``_add_version(table, toml, note, provenance) -> (version, created_at)``, ``_history(table,
    limit) -> rows`` and ``_version(table, version) -> row | None`` (header columns…, toml). Both backends
    inherit it, so the documents behave the same on SQLite and PostgreSQL."""

    def _add_version(self, table: str, toml: str, note: str, provenance: Sequence[Any]) -> tuple[int, float]:
        raise NotImplementedError

    def _history(self, table: str, limit: int) -> list[tuple[Any, ...]]:
        raise NotImplementedError

    def _version(self, table: str, version: int | None) -> tuple[Any, ...] | None:
        raise NotImplementedError

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

    # the units' transmission-error models (tcms_daq.transmission.te_model: one TOML per version, the TE workflow's)
    def add_te_model(self, toml: str, note: str = "", analysis_id: str | None = None,
                     run_id: str | None = None) -> BenchModelVersion:
        """Keep the next version of a unit's TE model (its whole ``tcms-te-model/1`` TOML); returns it."""
        version, created = self._add_version("te_models", toml, note, (analysis_id, run_id))
        return BenchModelVersion(version, created, note, text_sha256(toml), analysis_id, run_id)

    def te_model_history(self, limit: int = 100) -> list[BenchModelVersion]:
        """TE model versions (of every unit this bench tested), newest first."""
        return [BenchModelVersion(*row) for row in self._history("te_models", limit)]

    def te_model(self, version: int | None = None) -> tuple[BenchModelVersion, str] | None:
        """(version, TOML) of ``version`` (default: the latest); None when there is none."""
        row = self._version("te_models", version)
        return None if row is None else (BenchModelVersion(*row[:-1]), row[-1])


class TeModels(Protocol):
    """The versioned TE models a store keeps (both backends, through :class:`VersionedDocuments`)."""

    def add_te_model(self, toml: str, note: str = "", analysis_id: str | None = None,
                     run_id: str | None = None) -> BenchModelVersion: ...

    def te_model_history(self, limit: int = 100) -> list[BenchModelVersion]: ...

    def te_model(self, version: int | None = None) -> tuple[BenchModelVersion, str] | None: ...


class PeopleStore(Protocol):
    """What a run store keeps of people (tcms_daq.store.people): users, API tokens, sessions, the audit trail,
    saved plans and the admin's settings of its bench."""

    def add_user(self, name: str, role: str, password_hash: str) -> User: ...

    def user(self, name: str) -> User | None: ...

    def users(self) -> list[User]: ...

    def password_hash(self, name: str) -> str | None: ...

    def set_password_hash(self, name: str, password_hash: str) -> None: ...

    def set_user_disabled(self, name: str, disabled: bool) -> User: ...

    def add_api_token(self, name: str, token: str, label: str = "") -> None: ...

    def user_of_token(self, token: str) -> User | None: ...

    def add_session(self, name: str, session_id: str, lifetime_s: float = ...) -> float: ...

    def user_of_session(self, session_id: str) -> User | None: ...

    def end_session(self, session_id: str) -> None: ...

    def append_audit(self, user: str, action: str, *, role: str | None = None, target: str | None = None,
                     before: str | None = None, after: str | None = None, detail: str | None = None) -> None: ...

    def audit(self, query: AuditQuery | None = None, limit: int = 100, offset: int = 0) -> list[AuditEntry]: ...

    def count_audit(self, query: AuditQuery | None = None) -> int: ...

    def add_plan(self, name: str, request: Mapping[str, Any], created_by: str, note: str = "") -> SavedPlan: ...

    def plan(self, plan_id: int) -> SavedPlan | None: ...

    def plan_by_name(self, name: str, version: int | None = None) -> SavedPlan | None: ...

    def plans(self, all_versions: bool = False) -> list[SavedPlan]: ...

    def bench_settings(self) -> dict[str, Any]: ...

    def put_bench_settings(self, settings: Mapping[str, Any], updated_by: str) -> None: ...


class Store(PeopleStore, Protocol):
    """The run store the service, the CLI and the recorder use; both backends implement it."""

    bench_id: str | None
    bench_name: str | None
    recovered_run_ids: list[str]

    def describe(self) -> str:
        """Where the runs are, for people (a file path, or a database URL without its password)."""
        ...

    def close(self) -> None: ...

    def __enter__(self) -> Store: ...

    def __exit__(self, *exc: object) -> None: ...

    # runs
    def create_run(self, run_id: str, request: Mapping[str, Any], channels: Sequence[str], *,
                   profile: Mapping[str, Any] | None = None, config_snapshot: Mapping[str, Any] | None = None,
                   compensator_toml: str | None = None, compensation_version: int | None = None,
                   status: str = "queued") -> StoredRun: ...

    def set_status(self, run_id: str, status: str, *, error: str | None = None,
                   results: Mapping[str, Any] | None = None) -> None: ...

    def get_run(self, run_id: str) -> StoredRun | None: ...

    def list_runs(self, limit: int = 100, offset: int = 0, query: RunQuery | None = None, *,
                  brief: bool = False) -> list[StoredRun]:
        """Runs matching ``query``, newest first, without their config snapshot and TOML; ``brief``: their results
        reduced to :func:`brief_results` (PostgreSQL reduces them in the database)."""
        ...

    def count_runs(self, query: RunQuery | None = None) -> int: ...

    def total_runs(self, query: RunQuery | None = None, exact_up_to: int = EXACT_TOTAL_UP_TO) -> RunTotal:
        """The list's total: exact up to ``exact_up_to`` matching runs; past it a backend may estimate."""
        ...

    def count_by_status(self) -> dict[str, int]:
        """This bench's runs by status (the service's metrics)."""
        ...

    def headline_points(self, quantity: str, query: RunQuery, limit: int) -> list[HeadlinePoint]: ...

    # samples
    def append_samples(self, run_id: str, batches: Sequence[Mapping[str, np.ndarray]]) -> int: ...

    def iter_columns(self, run_id: str, chunk_samples: int = 65_536) -> Iterator[dict[str, np.ndarray]]: ...

    def read_columns(self, run_id: str) -> dict[str, np.ndarray]: ...

    def read_samples(self, run_id: str) -> Samples: ...

    # versioned documents of this bench
    def add_compensation(self, toml: str, note: str = "", rollback_of: int | None = None) -> CompensationVersion: ...

    def compensation_history(self, limit: int = 100) -> list[CompensationVersion]: ...

    def compensation(self, version: int | None = None) -> tuple[CompensationVersion, str] | None: ...

    def add_bench_model(self, toml: str, note: str = "", analysis_id: str | None = None,
                        run_id: str | None = None) -> BenchModelVersion: ...

    def bench_model_history(self, limit: int = 100) -> list[BenchModelVersion]: ...

    def bench_model(self, version: int | None = None) -> tuple[BenchModelVersion, str] | None: ...

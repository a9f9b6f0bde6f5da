"""People in the run store: users with roles, their API tokens and dashboard sessions, the audit trail, the
saved test plans and the admin's run-time settings of each bench. Both backends inherit :class:`PeopleRecords`,
written once over two primitives of theirs (``_people_query`` and ``_people_execute``, SQL with ``?``
placeholders), so users, audit, plans and settings behave the same on SQLite and PostgreSQL
(:class:`BenchSettingsRecords` adds the settings to them). Users, plans and the audit trail are the plant's (shared by every bench of a
PostgreSQL store); each audit entry names the bench it happened on.

The audit trail is append-only: the tables refuse UPDATE and DELETE (triggers on both backends), and nothing in
this module changes or removes an entry.

Secrets are never stored: passwords as argon2 hashes (:mod:`tcms_daq.service.users`), API tokens and session ids
as their SHA-256 (they are random 256-bit strings, so a fast hash suffices).
"""

from __future__ import annotations

import json
import re
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from tcms_daq.store.base import StoreError, check_time_window, iso, text_sha256

#: the roles of people, each with the rights of those before it (an engineer may do what an operator may)
ROLES: tuple[str, ...] = ("operator", "engineer", "admin")
#: letters, digits, '.', '_', '@', '-'; at most 64
USER_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._@-]{0,63}$")
PLAN_NAME = re.compile(r"^[^\x00-\x1f]{1,80}$")
SESSION_LIFETIME_S = 12 * 3600.0  # one shift

SQLITE_SCHEMA = """
CREATE TABLE IF NOT EXISTS users (
    name TEXT PRIMARY KEY,
    role TEXT NOT NULL,
    password_hash TEXT NOT NULL,
    disabled INTEGER NOT NULL DEFAULT 0,
    created_at REAL NOT NULL
);
CREATE TABLE IF NOT EXISTS api_tokens (
    token_sha256 TEXT PRIMARY KEY,
    user_name TEXT NOT NULL REFERENCES users(name),
    label TEXT NOT NULL,
    created_at REAL NOT NULL
);
CREATE TABLE IF NOT EXISTS sessions (
    session_sha256 TEXT PRIMARY KEY,
    user_name TEXT NOT NULL REFERENCES users(name),
    created_at REAL NOT NULL,
    expires_at REAL NOT NULL
);
CREATE TABLE IF NOT EXISTS audit (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    at REAL NOT NULL,
    user_name TEXT NOT NULL,
    role TEXT,
    action TEXT NOT NULL,
    target TEXT,
    before TEXT,
    after TEXT,
    detail TEXT,
    bench_id TEXT
);
CREATE INDEX IF NOT EXISTS audit_at ON audit(at);
CREATE TRIGGER IF NOT EXISTS audit_no_update BEFORE UPDATE ON audit
    BEGIN SELECT RAISE(ABORT, 'the audit trail is append-only'); END;
CREATE TRIGGER IF NOT EXISTS audit_no_delete BEFORE DELETE ON audit
    BEGIN SELECT RAISE(ABORT, 'the audit trail is append-only'); END;
CREATE TABLE IF NOT EXISTS plans (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    name TEXT NOT NULL,
    version INTEGER NOT NULL,
    created_at REAL NOT NULL,
    created_by TEXT NOT NULL,
    note TEXT NOT NULL,
    request TEXT NOT NULL,
    UNIQUE (name, version)
);
CREATE TABLE IF NOT EXISTS bench_settings (
    bench_key TEXT PRIMARY KEY,
    settings TEXT NOT NULL,
    updated_at REAL NOT NULL,
    updated_by TEXT NOT NULL
);
"""

#: the PostgreSQL migration that adds these tables (an entry of postgres_store.MIGRATIONS)
POSTGRES_MIGRATION = """
    CREATE TABLE users (
        name text PRIMARY KEY,
        role text NOT NULL,
        password_hash text NOT NULL,
        disabled integer NOT NULL DEFAULT 0,
        created_at double precision NOT NULL
    );
    CREATE TABLE api_tokens (
        token_sha256 text PRIMARY KEY,
        user_name text NOT NULL REFERENCES users(name),
        label text NOT NULL,
        created_at double precision NOT NULL
    );
    CREATE TABLE sessions (
        session_sha256 text PRIMARY KEY,
        user_name text NOT NULL REFERENCES users(name),
        created_at double precision NOT NULL,
        expires_at double precision NOT NULL
    );
    CREATE TABLE audit (
        id bigint GENERATED ALWAYS AS IDENTITY PRIMARY KEY,
        at double precision NOT NULL,
        user_name text NOT NULL,
        role text,
        action text NOT NULL,
        target text,
        before text,
        after text,
        detail text,
        bench_id text
    );
    CREATE INDEX audit_at ON audit (at);
    CREATE FUNCTION audit_append_only() RETURNS trigger LANGUAGE plpgsql AS
        $$ BEGIN RAISE EXCEPTION 'the audit trail is append-only'; END $$;
    CREATE TRIGGER audit_no_change BEFORE UPDATE OR DELETE ON audit
        FOR EACH ROW EXECUTE FUNCTION audit_append_only();
    CREATE TRIGGER audit_no_truncate BEFORE TRUNCATE ON audit
        FOR EACH STATEMENT EXECUTE FUNCTION audit_append_only();
    CREATE TABLE plans (
        id integer GENERATED ALWAYS AS IDENTITY PRIMARY KEY,
        name text NOT NULL,
        version integer NOT NULL,
        created_at double precision NOT NULL,
        created_by text NOT NULL,
        note text NOT NULL,
        request jsonb NOT NULL,
        UNIQUE (name, version)
    );
"""

#: the PostgreSQL migration that adds the admin's run-time settings of each bench (an entry of MIGRATIONS)
POSTGRES_SETTINGS_MIGRATION = """
    CREATE TABLE bench_settings (
        bench_key text PRIMARY KEY,
        settings jsonb NOT NULL,
        updated_at double precision NOT NULL,
        updated_by text NOT NULL
    );
"""


@dataclass(frozen=True)
class User:
    name: str
    role: str
    disabled: bool
    created_at: float

    def summary(self) -> dict[str, Any]:
        return {"name": self.name, "role": self.role, "disabled": self.disabled, "created_at": iso(self.created_at)}


@dataclass(frozen=True)
class AuditEntry:
    """One change of state: when, who (user name and role), what (``action`` on ``target``), the version or hash
    before and after, and a short detail."""

    id: int
    at: float
    user: str
    role: str | None
    action: str
    target: str | None
    before: str | None
    after: str | None
    detail: str | None
    bench_id: str | None

    def summary(self) -> dict[str, Any]:
        return {"id": self.id, "at": iso(self.at), "user": self.user, "role": self.role, "action": self.action,
                "target": self.target, "before": self.before, "after": self.after, "detail": self.detail,
                "bench_id": self.bench_id}


@dataclass(frozen=True)
class AuditQuery:
    """Which audit entries to list; None leaves a field open. ``action`` matches an action or its prefix
    (``compensation`` matches ``compensation.upload`` and ``compensation.rollback``)."""

    user: str | None = None
    action: str | None = None
    target: str | None = None
    since: float | None = None
    until: float | None = None

    def __post_init__(self) -> None:
        check_time_window(self.since, self.until)

    def where(self) -> tuple[str, list[Any]]:
        clauses: list[str] = []
        params: list[Any] = []
        if self.user is not None:
            clauses.append("user_name = ?")
            params.append(self.user)
        if self.action is not None:
            clauses.append("(action = ? OR action LIKE ? ESCAPE '\\')")
            params += [self.action, _like_escape(self.action) + ".%"]
        if self.target is not None:
            clauses.append("target = ?")
            params.append(self.target)
        if self.since is not None:
            clauses.append("at >= ?")
            params.append(self.since)
        if self.until is not None:
            clauses.append("at < ?")
            params.append(self.until + 0.001)
        return ("WHERE " + " AND ".join(clauses)) if clauses else "", params


def _like_escape(text: str) -> str:
    return text.replace("\\", "\\\\").replace("%", "\\%").replace("_", "\\_")


@dataclass(frozen=True)
class SavedPlan:
    """One version of a named test plan: the request body of ``POST /api/tests`` it starts (a TestRequest as
    JSON, without the unit's serial number and the customer, which each start gives)."""

    id: int
    name: str
    version: int
    created_at: float
    created_by: str
    note: str
    request: dict[str, Any]

    def summary(self) -> dict[str, Any]:
        return {"id": self.id, "name": self.name, "version": self.version, "created_at": iso(self.created_at),
                "created_by": self.created_by, "note": self.note, "request": self.request,
                "sha256": text_sha256(json.dumps(self.request, sort_keys=True))}


def check_role(role: str) -> str:
    if role not in ROLES:
        raise StoreError(f"unknown role {role!r} (known: {', '.join(ROLES)})")
    return role


def check_user_name(name: str) -> str:
    if not USER_NAME.match(name):
        raise StoreError(f"user name {name!r}: letters, digits, '.', '_', '@', '-' only (at most 64)")
    return name


class PeopleRecords:
    """Users, tokens, sessions, the audit trail and saved plans, over a backend's two primitives:
    ``_people_query(sql, params) -> rows`` and ``_people_execute(sql, params) -> rows changed``; SQL is written
    with ``?`` placeholders (the PostgreSQL backend turns them into ``%s``)."""

    bench_id: str | None

    def _people_query(self, sql: str, params: Sequence[Any] = ()) -> list[tuple[Any, ...]]:
        raise NotImplementedError

    def _people_execute(self, sql: str, params: Sequence[Any] = ()) -> int:
        raise NotImplementedError

    def _json_param(self, obj: Mapping[str, Any]) -> Any:
        """A JSON document as the backend stores it (SQLite: text)."""
        return json.dumps(dict(obj), allow_nan=False)

    # -- users ----------------------------------------------------------------------------------------------------
    def add_user(self, name: str, role: str, password_hash: str) -> User:
        """A new user (StoreError when the name is taken or invalid, or the role unknown)."""
        check_user_name(name)
        check_role(role)
        if self.user(name) is not None:
            raise StoreError(f"user {name!r} exists already")
        created = time.time()
        self._people_execute("INSERT INTO users (name, role, password_hash, disabled, created_at) "
                             "VALUES (?, ?, ?, 0, ?)", (name, role, password_hash, created))
        return User(name, role, False, created)

    def user(self, name: str) -> User | None:
        rows = self._people_query("SELECT name, role, disabled, created_at FROM users WHERE name = ?", (name,))
        return None if not rows else User(rows[0][0], rows[0][1], bool(rows[0][2]), rows[0][3])

    def users(self) -> list[User]:
        return [User(r[0], r[1], bool(r[2]), r[3])
                for r in self._people_query("SELECT name, role, disabled, created_at FROM users ORDER BY name")]

    def password_hash(self, name: str) -> str | None:
        rows = self._people_query("SELECT password_hash FROM users WHERE name = ?", (name,))
        return rows[0][0] if rows else None

    def set_password_hash(self, name: str, password_hash: str) -> None:
        if not self._people_execute("UPDATE users SET password_hash = ? WHERE name = ?", (password_hash, name)):
            raise StoreError(f"no user {name!r}")

    def set_user_disabled(self, name: str, disabled: bool) -> User:
        """Disable (or enable again) a user: a disabled user's sessions end and its tokens stop working."""
        if not self._people_execute("UPDATE users SET disabled = ? WHERE name = ?", (int(disabled), name)):
            raise StoreError(f"no user {name!r}")
        if disabled:
            self._people_execute("DELETE FROM sessions WHERE user_name = ?", (name,))
        found = self.user(name)
        assert found is not None
        return found

    # -- API tokens and sessions -------------------------------------------------------------------------------
    def add_api_token(self, name: str, token: str, label: str = "") -> None:
        """Keep (the SHA-256 of) a new API token of user ``name``."""
        if self.user(name) is None:
            raise StoreError(f"no user {name!r}")
        self._people_execute("INSERT INTO api_tokens (token_sha256, user_name, label, created_at) VALUES (?, ?, ?, ?)",
                             (text_sha256(token), name, label[:80], time.time()))

    def user_of_token(self, token: str) -> User | None:
        """The enabled user an API token belongs to (None: unknown token or disabled user)."""
        rows = self._people_query(
            "SELECT u.name, u.role, u.disabled, u.created_at FROM api_tokens t JOIN users u ON u.name = t.user_name "
            "WHERE t.token_sha256 = ?", (text_sha256(token),))
        if not rows or rows[0][2]:
            return None
        return User(rows[0][0], rows[0][1], False, rows[0][3])

    def add_session(self, name: str, session_id: str, lifetime_s: float = SESSION_LIFETIME_S) -> float:
        """Keep a new dashboard session of ``name``; returns when it expires (UNIX seconds)."""
        now = time.time()
        self._people_execute("DELETE FROM sessions WHERE expires_at < ?", (now,))
        self._people_execute("INSERT INTO sessions (session_sha256, user_name, created_at, expires_at) "
                             "VALUES (?, ?, ?, ?)", (text_sha256(session_id), name, now, now + lifetime_s))
        return now + lifetime_s

    def user_of_session(self, session_id: str) -> User | None:
        rows = self._people_query(
            "SELECT u.name, u.role, u.disabled, u.created_at FROM sessions s JOIN users u ON u.name = s.user_name "
            "WHERE s.session_sha256 = ? AND s.expires_at > ?", (text_sha256(session_id), time.time()))
        if not rows or rows[0][2]:
            return None
        return User(rows[0][0], rows[0][1], False, rows[0][3])

    def end_session(self, session_id: str) -> None:
        self._people_execute("DELETE FROM sessions WHERE session_sha256 = ?", (text_sha256(session_id),))

    # -- the audit trail ----------------------------------------------------------------------------------------
    def append_audit(self, user: str, action: str, *, role: str | None = None, target: str | None = None,
                     before: str | None = None, after: str | None = None, detail: str | None = None) -> None:
        """Append one entry (this store's bench); there is no way to change or remove one."""
        self._people_execute(
            "INSERT INTO audit (at, user_name, role, action, target, before, after, detail, bench_id) "
            "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)",
            (time.time(), user[:64], role, action[:64], _cut(target, 200), _cut(before, 200), _cut(after, 200),
             _cut(detail, 500), self.bench_id))

    def audit(self, query: AuditQuery | None = None, limit: int = 100, offset: int = 0) -> list[AuditEntry]:
        """Entries matching ``query``, newest first."""
        where, params = (query or AuditQuery()).where()
        rows = self._people_query(
            "SELECT id, at, user_name, role, action, target, before, after, detail, bench_id FROM audit "
            f"{where} ORDER BY id DESC LIMIT ? OFFSET ?", (*params, limit, offset))
        return [AuditEntry(*r) for r in rows]

    def count_audit(self, query: AuditQuery | None = None) -> int:
        where, params = (query or AuditQuery()).where()
        return int(self._people_query(f"SELECT count(*) FROM audit {where}", params)[0][0])

    # -- saved test plans ---------------------------------------------------------------------------------------
    def add_plan(self, name: str, request: Mapping[str, Any], created_by: str, note: str = "") -> SavedPlan:
        """The next version of plan ``name`` (version 1 for a new name)."""
        if not PLAN_NAME.match(name) or not name.strip():
            raise StoreError("a plan name is 1…80 printable characters")
        latest = self.plan_by_name(name)
        version = 1 if latest is None else latest.version + 1
        created = time.time()
        self._people_execute(
            "INSERT INTO plans (name, version, created_at, created_by, note, request) VALUES (?, ?, ?, ?, ?, ?)",
            (name, version, created, created_by, note[:200], self._json_param(request)))
        found = self.plan_by_name(name, version)
        assert found is not None
        return found

    def plan(self, plan_id: int) -> SavedPlan | None:
        rows = self._people_query(f"SELECT {_PLAN_COLUMNS} FROM plans WHERE id = ?", (plan_id,))
        return _plan(rows[0]) if rows else None

    def plan_by_name(self, name: str, version: int | None = None) -> SavedPlan | None:
        """Version ``version`` of plan ``name`` (default: its latest)."""
        if version is None:
            rows = self._people_query(f"SELECT {_PLAN_COLUMNS} FROM plans WHERE name = ? "
                                      "ORDER BY version DESC LIMIT 1", (name,))
        else:
            rows = self._people_query(f"SELECT {_PLAN_COLUMNS} FROM plans WHERE name = ? AND version = ?",
                                      (name, version))
        return _plan(rows[0]) if rows else None

    def plans(self, all_versions: bool = False) -> list[SavedPlan]:
        """The latest version of every plan by name (``all_versions``: every version, newest first)."""
        if all_versions:
            rows = self._people_query(f"SELECT {_PLAN_COLUMNS} FROM plans ORDER BY name, version DESC")
        else:
            rows = self._people_query(
                f"SELECT {_PLAN_COLUMNS} FROM plans p WHERE version = "
                "(SELECT max(version) FROM plans q WHERE q.name = p.name) ORDER BY name")
        return [_plan(r) for r in rows]


class BenchSettingsRecords(PeopleRecords):
    """The people records and the admin's run-time settings of this bench (one row per bench); the class both
    backends inherit."""

    def bench_settings(self) -> dict[str, Any]:
        """The settings an admin stored for this bench (``{}`` when none; validated by the service's model)."""
        rows = self._people_query("SELECT settings FROM bench_settings WHERE bench_key = ?", (self.bench_id or "",))
        if not rows:
            return {}
        return dict(rows[0][0]) if isinstance(rows[0][0], dict) else dict(json.loads(rows[0][0]))

    def put_bench_settings(self, settings: Mapping[str, Any], updated_by: str) -> None:
        """Replace this bench's settings (one row per bench; the audit trail keeps what they were)."""
        self._people_execute(
            "INSERT INTO bench_settings (bench_key, settings, updated_at, updated_by) VALUES (?, ?, ?, ?) "
            "ON CONFLICT (bench_key) DO UPDATE SET settings = excluded.settings, updated_at = excluded.updated_at, "
            "updated_by = excluded.updated_by",
            (self.bench_id or "", self._json_param(settings), time.time(), updated_by[:64]))


_PLAN_COLUMNS = "id, name, version, created_at, created_by, note, request"


def _plan(row: Sequence[Any]) -> SavedPlan:
    request = row[6] if isinstance(row[6], dict) else json.loads(row[6])
    return SavedPlan(int(row[0]), row[1], int(row[2]), row[3], row[4], row[5], request)


def _cut(text: str | None, n: int) -> str | None:
    return None if text is None else str(text)[:n]

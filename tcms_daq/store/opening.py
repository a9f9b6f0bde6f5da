"""Which run store a URL names, and opening it: ``postgresql://…`` (or ``postgres://…``) is the PostgreSQL
backend, ``sqlite:///path/file.sqlite3`` or no URL the SQLite file in the data directory."""

from __future__ import annotations

from pathlib import Path
from urllib.parse import urlsplit, urlunsplit

from tcms_daq.extras import require_extra
from tcms_daq.store.base import Store, StoreError

POSTGRES_SCHEMES = ("postgresql", "postgres")


def redact_url(url: str) -> str:
    """The URL without its password (for banners, errors and logs)."""
    parts = urlsplit(url)
    if parts.password is None:
        return url
    host = parts.hostname or ""
    netloc = f"{parts.username or ''}:***@{host}" + (f":{parts.port}" if parts.port else "")
    return urlunsplit((parts.scheme, netloc, parts.path, parts.query, parts.fragment))


def store_kind(url: str | None) -> str:
    """``postgresql`` or ``sqlite``; StoreError (one line) for another scheme."""
    if not url:
        return "sqlite"
    scheme = urlsplit(url).scheme.lower()
    if scheme in POSTGRES_SCHEMES:
        return "postgresql"
    if scheme == "sqlite":
        return "sqlite"
    raise StoreError(f"store URL {redact_url(url)!r}: unknown scheme {scheme!r} (use postgresql://… or sqlite:///…)")


def sqlite_path(url: str | None, data_dir: Path) -> Path:
    """The SQLite file a URL names (``sqlite:///abs/path``, ``sqlite:///relative``), or the data directory's."""
    from tcms_daq.store.sqlite_store import STORE_FILENAME

    if not url:
        return data_dir / STORE_FILENAME
    path = urlsplit(url).path
    if url.startswith("sqlite:////"):
        return Path(path)
    if not path.strip("/"):
        raise StoreError(f"store URL {url!r} names no file (sqlite:///path/to/runs.sqlite3)")
    return Path(path.lstrip("/"))


def open_store(url: str | None, data_dir: Path, *, bench_id: str | None = None, bench_name: str | None = None,
               recover: bool = True) -> Store:
    """Open the run store ``url`` names (None: SQLite in ``data_dir``) for a bench. ``recover`` marks the runs
    this bench left active as ``interrupted`` (a service starting); readers beside a service pass False."""
    if store_kind(url) == "postgresql":
        require_extra("plant", "the PostgreSQL run store", ("psycopg", "psycopg_pool"))
        from tcms_daq.store.postgres_store import PostgresRunStore

        assert url is not None
        return PostgresRunStore(url, recover=recover, bench_id=bench_id, bench_name=bench_name)
    from tcms_daq.store.sqlite_store import RunStore

    return RunStore(sqlite_path(url, data_dir), recover=recover, bench_id=bench_id, bench_name=bench_name)

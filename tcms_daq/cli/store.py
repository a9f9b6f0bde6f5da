"""``tcms store partitions|retire``: a plant's PostgreSQL run store over the years — its samples by month and the
retention policy that drops whole months of samples (the runs' records and results stay; their samples answer
410 Gone)."""

from __future__ import annotations

import argparse
import calendar
import time
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING

from tcms_daq.errors import ConfigError

if TYPE_CHECKING:  # psycopg is the [plant] extra: imported when a store is opened
    from tcms_daq.store.postgres_store import PostgresRunStore, SamplePartition


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("store", help="a plant's PostgreSQL run store: samples by month, retention",
                              description=__doc__)
    sub = p.add_subparsers(dest="store_command", metavar="SUBCOMMAND")
    parts = sub.add_parser("partitions", help="the month partitions of the samples: bounds, runs, size")
    retire = sub.add_parser("retire", help="drop the samples of whole months older than a cutoff (the retention "
                            "policy; records and results stay)")
    for q in (parts, retire):
        q.add_argument("--store", metavar="URL", default=None,
                       help="postgresql://user@host/db (default: $TCMS_STORE_URL)")
    when = retire.add_mutually_exclusive_group(required=True)
    when.add_argument("--keep-months", type=int, metavar="N",
                      help="keep this month and the N-1 before it; drop every older month")
    when.add_argument("--before", metavar="YYYY-MM",
                      help="drop every month before this one (UTC)")
    retire.add_argument("--dry-run", action="store_true", help="list what would be dropped, drop nothing")
    parts.set_defaults(func=_partitions)
    retire.set_defaults(func=_retire)
    p.set_defaults(func=lambda args: (p.print_help(), 2)[1])


def month_start(year: int, month: int) -> float:
    """UNIX seconds of the first instant of a UTC month (month may run past 12 or below 1)."""
    year, month = year + (month - 1) // 12, (month - 1) % 12 + 1
    return float(calendar.timegm((year, month, 1, 0, 0, 0)))


def cutoff_s(keep_months: int | None, before: str | None, now_s: float | None = None) -> float:
    """The retention cutoff (UNIX s): the start of the oldest month kept."""
    if keep_months is not None:
        if keep_months < 1:
            raise ConfigError(f"--keep-months must be at least 1 (this month), got {keep_months}")
        now = datetime.fromtimestamp(time.time() if now_s is None else now_s, UTC)
        return month_start(now.year, now.month - (keep_months - 1))
    assert before is not None
    try:
        month = datetime.strptime(before, "%Y-%m")
    except ValueError:
        raise ConfigError(f"--before {before!r}: expected YYYY-MM (a UTC month)") from None
    return month_start(month.year, month.month)


def _open(url: str | None) -> PostgresRunStore:
    from tcms_daq.settings import read_settings
    from tcms_daq.store.opening import open_store, redact_url, store_kind

    url = url or read_settings().store_url
    if not url or store_kind(url) != "postgresql":
        shown = redact_url(url) if url else "none"
        raise ConfigError(f"store URL {shown}: retention is the PostgreSQL store's (samples by month); give "
                          "--store postgresql://… or set TCMS_STORE_URL (an SQLite store is one file per bench)")
    from tcms_daq.store.postgres_store import PostgresRunStore

    store = open_store(url, Path("."), recover=False)
    assert isinstance(store, PostgresRunStore)
    return store


def _row(part: SamplePartition) -> str:
    month = datetime.fromtimestamp(part.from_s, UTC).strftime("%Y-%m")
    return f"{part.name:<24} {month}  {part.runs:>9} runs  {part.size_bytes / 2**20:>10.1f} MiB"


def _partitions(args: argparse.Namespace) -> int:
    with _open(args.store) as store:
        parts = store.sample_partitions()
    for part in parts:
        print(_row(part))
    total = sum(p.size_bytes for p in parts)
    print(f"{len(parts)} month(s) of samples, {total / 2**30:.2f} GiB")
    return 0


def _retire(args: argparse.Namespace) -> int:
    cutoff = cutoff_s(args.keep_months, args.before)
    with _open(args.store) as store:
        parts = store.retire_samples(cutoff, dry_run=args.dry_run)
    verb = "would drop" if args.dry_run else "dropped"
    for part in parts:
        print(f"{verb} {_row(part)}")
    kept = datetime.fromtimestamp(cutoff, UTC).strftime("%Y-%m")
    print(f"{verb} {len(parts)} month(s) of samples ({sum(p.runs for p in parts)} runs' samples, "
          f"{sum(p.size_bytes for p in parts) / 2**20:.1f} MiB); samples from {kept} on are kept")
    return 0

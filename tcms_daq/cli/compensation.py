"""``tcms compensation list|show|upload|rollback|from-model``: the bench's compensation versions in its run store,
as the service's ``/api/compensation`` keeps them (both call ``tcms_daq.store.compensation``).

The store is the one ``tcms serve`` opens for the bench of ``--config``: ``--store URL``, else
``$TCMS_STORE_URL``, else the config's ``[store] url``, else SQLite in ``--data-dir``. A version made here is in
use from the bench service's next start; a running service takes one at once through ``PUT /api/compensation``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from tcms_daq.cli.options import add_bench_config_options
from tcms_daq.config.models import CompensationChecks
from tcms_daq.errors import ConfigError, DataFormatError
from tcms_daq.settings import DEFAULT_DATA_DIR, read_settings
from tcms_daq.store.base import CompensationVersion, Store
from tcms_daq.store.compensation import CompensationRejected, CompensationVersions, UnknownVersion


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "compensation",
        help="list, show, upload or roll back the bench's compensation versions",
        description="The compensation versions of a bench in its run store (the newest is in use). Changes made "
        "here are in use from the bench service's next start (a running service: PUT /api/compensation).",
    )
    add_bench_config_options(p)
    p.add_argument("--data-dir", type=Path, default=None,
                   help=f"data directory of the SQLite run store (default: $TCMS_DATA_DIR or ./{DEFAULT_DATA_DIR})")
    p.add_argument("--store", metavar="URL", default=None,
                   help="run store URL (default: $TCMS_STORE_URL, else the config's [store] url, else --data-dir)")
    p.add_argument("--json", action="store_true", help="print JSON")
    actions = p.add_subparsers(dest="action", metavar="ACTION", required=True)
    actions.add_parser("list", help="every version, newest (in use) first")
    show = actions.add_parser("show", help="the TOML of a version (default: the one in use)")
    show.add_argument("version", type=int, nargs="?", default=None)
    upload = actions.add_parser("upload", help="keep a compensator TOML (checked for plausibility) as the next version")
    upload.add_argument("file", type=Path, help="compensator TOML or geometry TOML ('-': standard input)")
    upload.add_argument("--note", default="", help="what the version is (at most 200 characters)")
    rollback = actions.add_parser("rollback", help="use an earlier version again (kept as a new version)")
    rollback.add_argument("version", type=int)
    actions.add_parser("from-model", help="add the bench model's measuring-chain effects to the compensation in use")
    p.set_defaults(func=run)


def _open(args: argparse.Namespace) -> tuple[Store, CompensationChecks]:
    from tcms_daq.config import load_bench_config
    from tcms_daq.store import StoreError, open_store
    from tcms_daq.store.opening import sqlite_path, store_kind

    cfg = load_bench_config(args.config, args.overrides)
    env = read_settings()
    url = args.store or env.store_url or cfg.store.url
    data_dir = Path(args.data_dir or env.data_dir)
    try:
        if store_kind(url) == "sqlite" and args.action in ("list", "show") and not sqlite_path(url, data_dir).is_file():
            raise DataFormatError(f"no run store at {sqlite_path(url, data_dir)} (give --data-dir or --store)")
        data_dir.mkdir(parents=True, exist_ok=True)
        store = open_store(url, data_dir, bench_id=cfg.bench.bench_id, bench_name=cfg.bench.name, recover=False)
        return store, cfg.compensation_checks
    except StoreError as exc:
        raise ConfigError(str(exc)) from None


def _read(path: Path) -> str:
    try:
        return sys.stdin.read() if str(path) == "-" else path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise DataFormatError(f"{path}: cannot read ({getattr(exc, 'strerror', None) or exc})") from None


def _print_version(version: CompensationVersion, as_json: bool, what: str) -> None:
    if as_json:
        print(json.dumps(version.summary()))
    else:
        print(f"compensation version {version.version}: {what}" + (f" ({version.note})" if version.note else ""))


def run(args: argparse.Namespace) -> int:
    store, checks = _open(args)
    versions = CompensationVersions(store, checks)
    try:
        if args.action == "list":
            history = versions.history()
            if args.json:
                print(json.dumps([v.summary() for v in history]))
            for i, v in enumerate([] if args.json else history):
                s = v.summary()
                print(f"{v.version:>4}  {s['created_at']}  {s['sha256'][:12]}  {'in use  ' if i == 0 else '        '}"
                      f"{v.note}")
            if not history and not args.json:
                print(f"no compensation version in {store.describe()}")
        elif args.action == "show":
            version, text = versions.show(args.version)
            print(json.dumps({**version.summary(), "toml": text}) if args.json else text, end="" if not args.json
                  else "\n")
        elif args.action == "upload":
            _print_version(versions.upload(_read(args.file), args.note, source=str(args.file)), args.json, f"kept from {args.file}")
        elif args.action == "rollback":
            _print_version(versions.rollback(args.version), args.json, f"restores version {args.version}")
        else:
            done = versions.from_model()
            _print_version(done.compensation, args.json,
                           f"bench model version {done.bench_model.version} keeps the rest")
    except (CompensationRejected, UnknownVersion) as exc:
        raise DataFormatError(str(exc)) from None
    finally:
        store.close()
    return 0

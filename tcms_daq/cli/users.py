"""``tcms users add|list|disable|enable|token``: the people of the service, kept in the run store (SQLite in the
data directory, or the PostgreSQL store a plant's benches share). Every change is audited as ``cli:<login>``."""

from __future__ import annotations

import argparse
import getpass
import os
from pathlib import Path

from tcms_daq.cli.opcua_user import read_password
from tcms_daq.errors import DataFormatError
from tcms_daq.settings import DEFAULT_DATA_DIR, read_settings
from tcms_daq.store.people import ROLES


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "users", help="add, list, disable users of the service and issue their API tokens",
        description="Users of the dashboard and the API, with a role: operator (runs tests from saved plans, "
        "aborts), engineer (plans, compensation, bench model), admin (users). Kept in the run store.")
    p.add_argument("--data-dir", type=Path, default=None,
                   help=f"data directory of the SQLite run store (default: $TCMS_DATA_DIR or ./{DEFAULT_DATA_DIR})")
    p.add_argument("--store", metavar="URL", default=None,
                   help="run store URL, e.g. postgresql://user@host/db (default: $TCMS_STORE_URL, else --data-dir)")
    sub = p.add_subparsers(dest="users_command", metavar="ACTION", required=True)
    add = sub.add_parser("add", help="a new user (asks for the password; or reads one line from stdin)")
    add.add_argument("name", metavar="NAME")
    add.add_argument("--role", choices=ROLES, required=True)
    sub.add_parser("list", help="every user with its role")
    for action, text in (("disable", "disable a user (its sessions end, its tokens stop)"),
                         ("enable", "enable a disabled user again")):
        one = sub.add_parser(action, help=text)
        one.add_argument("name", metavar="NAME")
    token = sub.add_parser("token", help="print a new API token of a user (shown once; kept as a hash)")
    token.add_argument("name", metavar="NAME")
    token.add_argument("--label", default="", help="what the token is for (a script, a PC)")
    p.set_defaults(func=run)


def _who() -> str:
    try:
        return "cli:" + getpass.getuser()
    except (KeyError, OSError):
        return f"cli:uid {os.getuid()}"


def run(args: argparse.Namespace) -> int:
    from tcms_daq.service.users import audit, hash_password, new_api_token
    from tcms_daq.store import StoreError, open_store

    env = read_settings()
    try:
        store = open_store(args.store or env.store_url, Path(args.data_dir or env.data_dir), recover=False)
    except StoreError as exc:
        raise DataFormatError(str(exc)) from None
    try:
        command = args.users_command
        if command == "list":
            for user in store.users():
                print(f"{user.name:<24} {user.role:<9} {'disabled' if user.disabled else 'enabled'}")
            return 0
        if command == "add":
            hashed = hash_password(read_password())
            user = store.add_user(args.name, args.role, hashed)
            audit(store, _who(), "user.add", target=user.name, after=f"role {user.role}")
            print(f"added {user.name} ({user.role}) to {store.describe()}")
            return 0
        found = store.user(args.name)
        if found is None:
            raise DataFormatError(f"no user {args.name!r} in {store.describe()}")
        if command in ("disable", "enable"):
            store.set_user_disabled(args.name, command == "disable")
            audit(store, _who(), f"user.{command}", target=args.name,
                  before="disabled" if found.disabled else "enabled", after=f"{command}d")
            print(f"{args.name} {command}d")
            return 0
        token = new_api_token(store, args.name, args.label)
        audit(store, _who(), "user.token", target=args.name, detail=args.label or None)
        print(token)
        return 0
    except StoreError as exc:
        raise DataFormatError(str(exc)) from None
    finally:
        store.close()

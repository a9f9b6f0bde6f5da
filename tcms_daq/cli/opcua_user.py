"""``tcms opcua-user NAME``: the line that gives user NAME access to the OPC UA server ([opcua.users] of the bench
configuration), its password kept only as a hash."""

from __future__ import annotations

import argparse
import getpass
import json
import re
import sys

from tcms_daq.errors import ConfigError

NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._@-]{0,63}$")


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "opcua-user",
        help="print the [opcua.users] line of an OPC UA user (the password as a hash)",
        description="Ask for a password (twice; or read one line from stdin when it is not a terminal) and print "
        "the TOML line that lets NAME connect to the OPC UA server: put it under [opcua.users] in the bench "
        "configuration. Only a scrypt hash of the password is printed.",
    )
    p.add_argument("name", metavar="NAME", help="user name (letters, digits, . _ @ -; at most 64)")
    p.set_defaults(func=run)


def read_password() -> str:
    """A password asked twice on a terminal, or one line of stdin when it is not one."""
    if not sys.stdin.isatty():
        return sys.stdin.readline().rstrip("\r\n")
    first = getpass.getpass("password: ")
    if getpass.getpass("again: ") != first:
        raise ConfigError("the two passwords differ")
    return first


def run(args: argparse.Namespace) -> int:
    from tcms_daq.service.passwords import hash_password

    if not NAME.match(args.name):
        raise ConfigError(f"user name {args.name!r}: letters, digits, '.', '_', '@', '-' only (at most 64)")
    password = read_password()
    if len(password) < 8:
        raise ConfigError("the password needs at least 8 characters")
    print(f"{json.dumps(args.name)} = {json.dumps(hash_password(password))}")
    return 0

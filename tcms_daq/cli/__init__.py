"""The ``tcms`` command line.

Each subcommand lives in its own module of this package and exposes ``register(subparsers)``; ``register``
adds a parser whose ``func`` default is called with the parsed namespace and returns the exit code. Modules are
discovered, so adding a command means adding a module.

Errors: a ``TcmsError`` raised by a command is printed as one line on stderr (``tcms: error: …``) and the exit
code is 2; argparse usage errors exit 2 as well.
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys
from typing import Any

from tcms_daq.cli.options import apply_sim_urls
from tcms_daq.errors import TcmsError


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The ``tcms`` parser with every command; with ``command`` (the name given on the command line) only that
    command's module is imported when it registers it (each module imports what its command needs: the others
    cost a second or more of start-up), else every module."""
    names = sorted(m.name for m in pkgutil.iter_modules(__path__) if not m.name.startswith("_"))
    if command is not None:
        module = command.replace("-", "_")
        if module in names:
            parser, subparsers = _parser()
            _register(module, subparsers)
            if command in subparsers.choices:
                return parser
    parser, subparsers = _parser()
    for name in names:
        _register(name, subparsers)
    return parser


def _parser() -> tuple[argparse.ArgumentParser, Any]:
    parser = argparse.ArgumentParser(
        prog="tcms", description="Torsional characteristic test bench for precision reducers."
    )
    return parser, parser.add_subparsers(dest="command", metavar="COMMAND")


def _register(name: str, subparsers: Any) -> None:
    register = getattr(importlib.import_module(f"{__name__}.{name}"), "register", None)
    if register is not None:
        register(subparsers)


def main(argv: list[str] | None = None) -> int:
    given = sys.argv[1:] if argv is None else argv
    parser = build_parser(given[0] if given and not given[0].startswith("-") else None)
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        apply_sim_urls(args)
        return int(args.func(args) or 0)
    except TcmsError as exc:
        print(f"tcms: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("tcms: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

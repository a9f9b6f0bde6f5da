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

from tcms_daq.cli.options import apply_sim_urls
from tcms_daq.errors import TcmsError


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="tcms", description="Torsional characteristic test bench for precision reducers."
    )
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    for info in sorted(pkgutil.iter_modules(__path__), key=lambda m: m.name):
        if info.name.startswith("_"):
            continue
        module = importlib.import_module(f"{__name__}.{info.name}")
        register = getattr(module, "register", None)
        if register is not None:
            register(subparsers)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
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

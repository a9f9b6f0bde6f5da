"""The optional parts of TCMS-DAQ and the extra that installs each (``pip install 'tcms-daq[plant]'``).

What ``tcms serve`` imports at start is a runtime dependency; a part a bench can run without is an extra, imported
only where it is used, and its absence is one line naming the extra (``scripts/setup --test`` installs them all):

* ``plant``: the PostgreSQL run store of a plant's benches (psycopg, psycopg-pool) and the OPC UA server (asyncua);
* ``exports``: the MDF4 export of a run's samples (asammdf).
"""

from __future__ import annotations

import importlib.util

from tcms_daq.errors import TcmsError

#: extra -> the top-level modules it installs (pyproject.toml's [project.optional-dependencies] holds the pins;
#: tests/architecture/test_packaging.py holds this table to it)
EXTRAS: dict[str, tuple[str, ...]] = {
    "plant": ("psycopg", "psycopg_pool", "asyncua"),
    "exports": ("asammdf",),
}


class MissingExtra(TcmsError):
    """An optional part is used without the extra that installs it."""


def missing_extra_message(extra: str, what: str) -> str:
    """One line: ``what`` needs the extra, and the command that installs it."""
    return f"{what} needs the optional [{extra}] dependencies: pip install 'tcms-daq[{extra}]'"


def require_extra(extra: str, what: str, modules: tuple[str, ...] | None = None) -> None:
    """MissingExtra (one line) unless the modules of ``extra`` (or just ``modules`` of it) are importable."""
    wanted = EXTRAS[extra] if modules is None else modules
    if any(importlib.util.find_spec(name) is None for name in wanted):
        raise MissingExtra(missing_extra_message(extra, what))

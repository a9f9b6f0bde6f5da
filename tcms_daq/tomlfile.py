"""The project's versioned TOML documents (a bench model, a unit's TE model): read with their ``format`` checked."""

from __future__ import annotations

import tomllib
from typing import Any

from tcms_daq.errors import DataFormatError


def load_formatted_toml(text: str, source: str, fmt: str) -> dict[str, Any]:
    """The TOML document in ``text`` whose ``format`` key must be ``fmt``; DataFormatError with one line naming
    ``source`` and the problem otherwise."""
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise DataFormatError(f"{source}: not valid TOML ({exc})") from None
    if doc.get("format") != fmt:
        raise DataFormatError(f"{source}: format must be {fmt!r}")
    return doc

"""HBM AED torque amplifier, ASCII command set (COF3): commands end with ';' or LF; ``MSV?`` answers one signed
7-digit value ``+0012345\\r\\n`` = (sensor torque − tare) / nominal torque × NOV (NOV 0 = the factory scaling);
``+9999999`` marks an overflow or a sensor error."""

from __future__ import annotations

import re

MSV_RE = re.compile(rb"^([+-]\d{7})\r\n$")
MSV_REPLY_LENGTH = 10
OVERFLOW_VALUE = 9_999_999
FACTORY_NOMINAL_OUTPUT = 1_000_000
MAX_NOV = 999_999  # NOV is a 6-digit setting; 0 selects the factory scaling


def format_msv(counts: int) -> bytes:
    """The ``MSV?`` reply for a value in output counts (clamped to ±OVERFLOW_VALUE)."""
    return f"{max(-OVERFLOW_VALUE, min(OVERFLOW_VALUE, int(counts))):+08d}\r\n".encode("ascii")

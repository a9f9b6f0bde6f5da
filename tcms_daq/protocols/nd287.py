"""Heidenhain ND 287 serial output (RS-232): the host sends STX; the display answers one 17-byte frame::

    sign  value(10 chars, leading blanks)  ' '  unit  sorting  series  CR LF
    b'-   12.3456 G  \\r\\n'   -> -12.3456 deg

Units: 'G' degrees, 'R' radians, 'M' degrees-minutes-seconds packed as ``D.MMSSs…`` (12.3015 = 12°30'15"),
'?' = fault (encoder signal error).
"""

from __future__ import annotations

import math
import re

from tcms_daq.units import ARCSEC_PER_DEG, ARCSEC_PER_RAD

STX = b"\x02"  # measured value retrieval (Ctrl-B)
DC1 = b"\x11"  # continue output (after DC3)
ENQ = b"\x05"  # error message enquiry: STX + 13-character error text + CR LF
FRAME_LENGTH = 17
FRAME_RE = re.compile(rb"^([+-])([ 0-9.]{10}) (.)(.)(.)\r\n$")
ANGLE_UNITS = ("G", "R", "M")


def dms_to_deg(packed: float) -> float:
    """``D.MMSSs…`` (degrees, minutes, seconds packed in one decimal number) -> decimal degrees."""
    sign = -1.0 if packed < 0 else 1.0
    text = f"{abs(packed):.8f}"
    deg_text, frac = text.split(".")
    minutes = int(frac[0:2])
    seconds = float(frac[2:4] + "." + frac[4:])
    if minutes >= 60 or seconds >= 60.0:
        raise ValueError(f"{packed!r} is not a valid D.MMSS angle")
    return sign * (int(deg_text) + minutes / 60.0 + seconds / 3600.0)


def deg_to_dms_packed(angle_deg: float) -> float:
    """Decimal degrees -> ``D.MMSSs`` packed number (12.5041667° -> 12.3015)."""
    sign = -1.0 if angle_deg < 0 else 1.0
    total_s = abs(angle_deg) * 3600.0
    deg = math.floor(total_s / 3600.0)
    minutes = math.floor((total_s - deg * 3600.0) / 60.0)
    seconds = total_s - deg * 3600.0 - minutes * 60.0
    return sign * (deg + minutes / 100.0 + seconds / 10000.0)


def value_to_arcsec(value: float, unit: bytes) -> float:
    """A frame's value in its unit (b'G', b'R', b'M') -> arcsec; ValueError for any other unit or a bad D.MMSS."""
    if unit == b"G":
        return value * ARCSEC_PER_DEG
    if unit == b"R":
        return value * ARCSEC_PER_RAD
    if unit == b"M":
        return dms_to_deg(value) * ARCSEC_PER_DEG
    raise ValueError(f"unit {unit!r} is not an angle unit (G, R, M)")


#: the series character of the ND 287's coupled-axes display X1 − X2 (with its X2 scaling factor: X1 − k·X2);
#: '1'/'2' are the single inputs, 'A' X1 + X2, 'F' f(X1, X2) (protocols.md §1.3)
SERIES_COUPLED_DIFFERENCE = "S"


def format_frame(angle_arcsec: float, *, unit: str = "G", decimals: int = 5, fault: bool = False,
                 series: str = " ") -> bytes:
    """The 17-byte frame for an angle in arcsec; ``fault`` gives unit '?' (value field still filled); a value
    too wide for the 10-character field is reported as a fault; ``series`` is the frame's last character before
    CR LF (blank, or what the display shows: ``S`` for the coupled X1 − X2)."""
    if unit == "G":
        value = angle_arcsec / ARCSEC_PER_DEG
    elif unit == "R":
        value = angle_arcsec / ARCSEC_PER_RAD
    elif unit == "M":
        value = deg_to_dms_packed(angle_arcsec / ARCSEC_PER_DEG)
    else:
        raise ValueError(f"ND 287 unit must be G, R or M, got {unit!r}")
    field = f"{abs(value):10.{decimals}f}"
    if len(field) != 10:
        field, fault = "9" * 10, True
    sign = "-" if value < 0 and float(field) != 0.0 else "+"
    if len(series) != 1:
        raise ValueError(f"series must be one character, got {series!r}")
    return f"{sign}{field} {'?' if fault else unit} {series}\r\n".encode("ascii")

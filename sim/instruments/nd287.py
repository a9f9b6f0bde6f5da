"""ND 287 position display simulator: answers STX (0x02) with a 17-byte frame of the latest encoder angle.

Frame: sign + value (10 chars, leading blanks) + ' ' + unit + sorting + series + CR LF (protocols.md §1.3).
Units: 'G' degrees (default), 'R' radians, 'M' packed D.MMSS; an encoder fault answers with unit '?'.
DC3 (0x13) holds output, DC1 (0x11) releases it (requests received meanwhile are answered on release);
ENQ (0x05) answers STX + a 13-character error text + CR LF. Other bytes are ignored.
"""

from __future__ import annotations

import asyncio
import math
from collections.abc import Callable

from sim.instruments.tcp import TcpInstrumentServer
from tcms_daq.units import ARCSEC_PER_DEG, ARCSEC_PER_RAD

STX, DC1, DC3, ENQ = 0x02, 0x11, 0x13, 0x05
GARBAGE_FRAME = b"@@#\x7f+12.3!!?? G\r\n"  # 17 bytes, CR LF-terminated, not an ND frame


def deg_to_dms_packed(angle_deg: float) -> float:
    """Decimal degrees -> ``D.MMSSs`` packed number (12.5041667° -> 12.3015)."""
    sign = -1.0 if angle_deg < 0 else 1.0
    total_s = abs(angle_deg) * 3600.0
    deg = math.floor(total_s / 3600.0)
    minutes = math.floor((total_s - deg * 3600.0) / 60.0)
    seconds = total_s - deg * 3600.0 - minutes * 60.0
    return sign * (deg + minutes / 100.0 + seconds / 10000.0)


def format_frame(angle_arcsec: float, *, unit: str = "G", decimals: int = 5, fault: bool = False) -> bytes:
    """The 17-byte frame for an angle in arcsec; ``fault`` gives unit '?' (value field still filled)."""
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
        field, fault = "9" * 10, True  # overflow of the display: report it as a fault
    sign = "-" if value < 0 and float(field) != 0.0 else "+"
    return f"{sign}{field} {'?' if fault else unit}  \r\n".encode("ascii")


class ND287Server(TcpInstrumentServer):
    name = "ND 287 sim"
    DEVICE_FAULTS = ("encoder_fault",)

    def __init__(
        self,
        angle_arcsec: Callable[[], float],
        *,
        host: str = "127.0.0.1",
        port: int = 0,
        unit: str = "G",
        decimals: int = 5,
        reply_delay_s: float = 0.0,
    ):
        super().__init__(host, port, reply_delay_s)
        format_frame(0.0, unit=unit, decimals=decimals)  # validate the display settings now
        self.angle_arcsec = angle_arcsec
        self.unit = unit
        self.decimals = int(decimals)

    def frame(self) -> bytes:
        return format_frame(
            self.angle_arcsec(), unit=self.unit, decimals=self.decimals, fault=self.fault == "encoder_fault"
        )

    async def serve_connection(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        held = False
        pending = 0
        while True:
            data = await reader.read(256)
            if not data:
                return
            for byte in data:
                if byte == DC3:
                    held = True
                elif byte == DC1:
                    held = False
                    for _ in range(pending):
                        await self.reply(writer, self.frame(), GARBAGE_FRAME)
                    pending = 0
                elif byte == STX:
                    if held:
                        pending += 1
                    else:
                        # latch at reception, like the real display
                        await self.reply(writer, self.frame(), GARBAGE_FRAME)
                elif byte == ENQ:
                    text = "ENCODER ERROR" if self.fault == "encoder_fault" else " " * 13
                    await self.reply(writer, b"\x02" + text.encode("ascii") + b"\r\n", GARBAGE_FRAME)

"""ND 287 position display simulator: answers STX (0x02) with a 17-byte frame of the latest encoder angle.

Frame: sign + value (10 chars, leading blanks) + ' ' + unit + sorting + series + CR LF
(``tcms_daq.protocols.nd287``).
Units: 'G' degrees (default), 'R' radians, 'M' packed D.MMSS; an encoder fault answers with unit '?'.
DC3 (0x13) holds output, DC1 (0x11) releases it (requests received meanwhile are answered on release);
ENQ (0x05) answers STX + a 13-character error text + CR LF. Other bytes are ignored.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable

from tcms_daq.sim.instruments.tcp import TcpInstrumentServer

from tcms_daq.protocols.nd287 import format_frame

STX, DC1, DC3, ENQ = 0x02, 0x11, 0x13, 0x05
GARBAGE_FRAME = b"@@#\x7f+12.3!!?? G\r\n"  # 17 bytes, CR LF-terminated, not an ND frame


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

"""ND 287 position display simulator: answers STX (0x02) with a 17-byte frame of the latest encoder angle.

Frame: sign + value (10 chars, leading blanks) + ' ' + unit + sorting + series + CR LF
(``tcms_daq.protocols.nd287``).
Units: 'G' degrees (default), 'R' radians, 'M' packed D.MMSS; an encoder fault answers with unit '?'.
DC3 (0x13) holds output, DC1 (0x11) releases it (requests received meanwhile are answered on release);
ENQ (0x05) answers STX + a 13-character error text + CR LF. Other bytes are ignored.

Power cycles (``start()`` after a ``stop()``: the control channel's ``restart``, or ``power_cycle()`` alone for
a display that is switched off and on while its serial link stays open): a real ND 287 on an incremental
encoder (the RON 786 has one reference mark or distance-coded ones, ``/work/shared/reference/protocols.md``
§1.1) loses its datum with its power: it counts from the position it is switched on at until the reference marks
are traversed again, and it comes back with its power-on settings (``docs/hardware.md``: "a display offset or
reference mark set on the ND 287 is part of the reading"). The simulator reads 0 at the position it is powered
on at (a new offset, ``datum_offset_arcsec``, against the datum it had), and its unit and decimals are the
power-on ones again. The first start keeps the datum (the bench was set up with its reference mark traversed).
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
        series: str = " ",
    ):
        super().__init__(host, port, reply_delay_s)
        format_frame(0.0, unit=unit, decimals=decimals, series=series)  # validate the display settings now
        self.series = series  # "S": the coupled-axes display X1 − k·X2 (the second axis's transmission error)
        self.angle_arcsec = angle_arcsec
        self.power_on_unit, self.power_on_decimals = unit, int(decimals)
        self.unit, self.decimals = unit, int(decimals)
        self.datum_offset_arcsec = 0.0  # added to the encoder's angle: 0 until the first power cycle
        self.power_cycles = 0
        self._started_before = False

    def power_cycle(self) -> None:
        """Switched off and on: the count restarts at 0 where the encoder is now, the settings are the power-on
        ones (the serial connections are left as they are: ``stop()``/``start()`` drop them)."""
        self.datum_offset_arcsec = -self.angle_arcsec()
        self.unit, self.decimals = self.power_on_unit, self.power_on_decimals
        self.power_cycles += 1

    async def start(self) -> int:
        if self._started_before and not self.running:
            self.power_cycle()
        self._started_before = True
        return await super().start()

    def frame(self) -> bytes:
        return format_frame(self.angle_arcsec() + self.datum_offset_arcsec, unit=self.unit, decimals=self.decimals,
                            fault=self.fault == "encoder_fault", series=self.series)

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

"""HBM AED-style torque amplifier simulator (ASCII command set, protocols.md §2.2).

Commands end with ';' or LF, case-insensitive; a lone terminator just clears. Implemented: ``COF3`` (ASCII
value format; other formats are rejected), ``COF?``, ``NOV<n>``/``NOV?``, ``TAR`` (tare at the present
reading), ``TAV?`` (tare value in output counts) and ``TAV<±n>`` (set it: a host restores its zero after the
amplifier was power-cycled), ``MSV?`` (``+0012345\\r\\n``), ``IDN?``. Settings answer
``0\\r\\n``, unknown or invalid commands ``?\\r\\n``. Value = (sensor torque − tare) / nominal torque × NOV
(NOV 0 = 1 000 000). The device fault ``sensor_fault`` makes ``MSV?`` return the overflow marker ``+9999999``.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable

from tcms_daq.sim.instruments.tcp import TcpInstrumentServer

from tcms_daq.protocols.aed import FACTORY_NOMINAL_OUTPUT, OVERFLOW_VALUE, format_msv

GARBAGE_REPLY = b"+00x1?3#\r\n"  # 10 bytes, CR LF-terminated, not a measured value


TARE_READINGS = 16  # TAR takes the mean of this many readings of the sensor (the amplifier's filter)


class AEDServer(TcpInstrumentServer):
    name = "AED sim"
    DEVICE_FAULTS = ("sensor_fault",)

    def __init__(
        self,
        torque_nm: Callable[[], float],
        *,
        nominal_torque_nm: float = 2000.0,
        host: str = "127.0.0.1",
        port: int = 0,
        reply_delay_s: float = 0.0,
        filtered_nm: Callable[[], float] | None = None,
    ):
        """``filtered_nm``: the amplifier's filtered measured value, which ``TAR`` takes (default: the mean of
        TARE_READINGS readings of ``torque_nm``)."""
        super().__init__(host, port, reply_delay_s)
        self.filtered_nm = filtered_nm
        if not nominal_torque_nm > 0:
            raise ValueError(f"AED sim: nominal_torque_nm must be > 0, got {nominal_torque_nm}")
        self.torque_nm = torque_nm
        self.nominal_torque_nm = float(nominal_torque_nm)
        self.reset_settings()

    def reset_settings(self) -> None:
        """Power-on settings (a restart of the amplifier)."""
        self.cof = 3
        self.nov = 0
        self.tare_nm = 0.0

    async def start(self) -> int:
        self.reset_settings()
        return await super().start()

    @property
    def counts_per_nm(self) -> float:
        return (self.nov or FACTORY_NOMINAL_OUTPUT) / self.nominal_torque_nm

    def measured_value(self) -> int:
        if self.fault == "sensor_fault":
            return OVERFLOW_VALUE
        return round((self.torque_nm() - self.tare_nm) * self.counts_per_nm)

    def execute(self, command: str) -> bytes | None:
        """One command (without terminator) -> reply bytes, or None for no reply."""
        cmd = command.strip().upper()
        if not cmd:
            return None
        if cmd == "MSV?":
            return format_msv(self.measured_value())
        if cmd == "COF?":
            return f"{self.cof}\r\n".encode("ascii")
        if cmd == "NOV?":
            return f"{self.nov}\r\n".encode("ascii")
        if cmd == "TAV?":
            return f"{round(self.tare_nm * self.counts_per_nm):+08d}\r\n".encode("ascii")
        if cmd == "IDN?":
            return b"HBM,AED-SIM,TCMS,1.0\r\n"
        if cmd == "TAR":  # at the present reading, filtered as the amplifier's measured value is (its ICR)
            self.tare_nm = (self.filtered_nm() if self.filtered_nm is not None
                            else sum(self.torque_nm() for _ in range(TARE_READINGS)) / TARE_READINGS)
            return b"0\r\n"
        if cmd.startswith("TAV") and cmd[3:].lstrip("+-").isdigit() and len(cmd) > 3:
            counts = int(cmd[3:])
            if abs(counts) >= OVERFLOW_VALUE:
                return b"?\r\n"
            self.tare_nm = counts / self.counts_per_nm
            return b"0\r\n"
        if cmd.startswith("COF") and cmd[3:].isdigit():
            if int(cmd[3:]) != 3:
                return b"?\r\n"  # only the ASCII format is simulated
            self.cof = 3
            return b"0\r\n"
        if cmd.startswith("NOV") and cmd[3:].isdigit():
            nov = int(cmd[3:])
            if nov > 999_999:
                return b"?\r\n"
            self.nov = nov
            return b"0\r\n"
        return b"?\r\n"

    async def serve_connection(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        buffer = b""
        while True:
            data = await reader.read(256)
            if not data:
                return
            buffer += data.replace(b"\n", b";")
            while b";" in buffer:
                raw, buffer = buffer.split(b";", 1)
                answer = self.execute(raw.decode("ascii", errors="replace"))
                if answer is not None:
                    await self.reply(writer, answer, GARBAGE_REPLY)
            if len(buffer) > 100:  # the real unit has a 100-character input buffer
                buffer = b""

"""A fault-injecting TCP proxy for any request/reply protocol on TCP (Modbus TCP/RTU-over-TCP, socketcand).

Put it in front of a simulator to break replies the simulator itself always forms correctly: ``mute`` drops
every reply, ``garbage`` replaces each reply chunk by the same number of junk bytes, ``partial`` forwards
only the first half of each reply chunk. ``stop()`` drops every connection (a cable pulled).
"""

from __future__ import annotations

import asyncio

from tcms_daq.sim.instruments.tcp import COMMON_FAULTS, TcpServer


class FaultProxy(TcpServer):
    name = "fault proxy"

    def __init__(self, upstream_host: str, upstream_port: int, *, host: str = "127.0.0.1", port: int = 0):
        super().__init__(host, port)
        self.upstream = (upstream_host, upstream_port)

    @property
    def faults(self) -> tuple[str, ...]:
        return COMMON_FAULTS

    async def serve_connection(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        try:
            up_reader, up_writer = await asyncio.open_connection(*self.upstream)
        except OSError:
            return
        self.track(up_writer)

        async def pump(src: asyncio.StreamReader, dst: asyncio.StreamWriter, replies: bool) -> None:
            while data := await src.read(4096):
                if replies:
                    if self.fault == "mute":
                        continue
                    if self.fault == "garbage":
                        data = bytes((0xA5 + 7 * i) & 0xFF for i in range(len(data)))
                    elif self.fault == "partial":
                        data = data[: max(1, len(data) // 2)]
                dst.write(data)
                await dst.drain()

        tasks = [asyncio.create_task(pump(reader, up_writer, False)),
                 asyncio.create_task(pump(up_reader, writer, True))]
        try:
            await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
        finally:
            for task in tasks:
                task.cancel()
            self._writers.discard(up_writer)
            up_writer.close()

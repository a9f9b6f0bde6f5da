"""A fault-injecting TCP proxy for any request/reply protocol on TCP (Modbus TCP/RTU-over-TCP, socketcand).

Put it in front of a simulator to break replies the simulator itself always forms correctly: ``mute`` drops
every reply, ``garbage`` replaces each reply chunk by the same number of junk bytes, ``partial`` forwards
only the first half of each reply chunk. ``stop()`` drops every connection (a cable pulled).
"""

from __future__ import annotations

import asyncio
import contextlib

from sim.instruments.tcp import COMMON_FAULTS


class FaultProxy:
    name = "fault proxy"

    def __init__(self, upstream_host: str, upstream_port: int, *, host: str = "127.0.0.1", port: int = 0):
        self.upstream = (upstream_host, upstream_port)
        self.host = host
        self.port = port
        self.fault: str | None = None
        self._server: asyncio.base_events.Server | None = None
        self._writers: set[asyncio.StreamWriter] = set()

    def inject(self, fault: str | None) -> None:
        if fault is not None and fault not in COMMON_FAULTS:
            raise ValueError(f"{self.name}: unknown fault {fault!r} (known: {', '.join(COMMON_FAULTS)})")
        self.fault = fault

    async def start(self) -> int:
        if self._server is None:
            self._server = await asyncio.start_server(self._handle, self.host, self.port)
            self.port = self._server.sockets[0].getsockname()[1]
        return self.port

    async def stop(self) -> None:
        server, self._server = self._server, None
        if server is not None:
            server.close()
        for writer in list(self._writers):
            writer.close()
        self._writers.clear()
        if server is not None:
            with contextlib.suppress(Exception):
                await asyncio.wait_for(server.wait_closed(), 1.0)

    async def _handle(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        try:
            up_reader, up_writer = await asyncio.open_connection(*self.upstream)
        except OSError:
            writer.close()
            return
        self._writers.update((writer, up_writer))

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
        except (ConnectionError, asyncio.CancelledError):
            pass
        finally:
            for task in tasks:
                task.cancel()
            for w in (writer, up_writer):
                self._writers.discard(w)
                w.close()

"""asyncio TCP server bases: ``TcpServer`` (listener, connections, fault switch) for every simulator on TCP
(instrument servers, the fault proxy, the socketcand hub), and ``TcpInstrumentServer`` for the serial-line
instrument simulators (ND 287, AED).

The driver side opens ``socket://host:port`` with pyserial. ``stop()`` closes the listener *and* every open
connection, so a driver sees the link drop exactly as if the instrument had been power-cycled; ``start()``
again re-binds the same port (a simulator restart).

Fault injection (``inject(name)``, ``inject(None)`` clears): ``mute`` (swallow requests), ``garbage`` (a complete
reply that breaks the framing), ``partial`` (the first bytes of a reply, then silence), plus the instrument's
own device faults listed in ``DEVICE_FAULTS``.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging

COMMON_FAULTS = ("mute", "garbage", "partial")

log = logging.getLogger(__name__)


class TcpServer:
    """A TCP listener on ``host:port`` (0 = ephemeral, known after ``start()``) that keeps track of its open
    connections. Subclasses implement ``serve_connection`` and list the faults ``inject`` accepts."""

    name = "TCP server"

    def __init__(self, host: str = "127.0.0.1", port: int = 0):
        self.host = host
        self.port = port
        self.fault: str | None = None
        self._server: asyncio.base_events.Server | None = None
        self._writers: set[asyncio.StreamWriter] = set()

    @property
    def faults(self) -> tuple[str, ...]:
        return ()

    def inject(self, fault: str | None) -> None:
        """Switch a fault on (``None`` clears it); ValueError for a fault this server does not know."""
        if fault is not None and fault not in self.faults:
            raise ValueError(f"{self.name}: unknown fault {fault!r} (known: {', '.join(self.faults)})")
        self.fault = fault

    @property
    def running(self) -> bool:
        return self._server is not None

    async def start(self) -> int:
        if self._server is None:
            self._server = await asyncio.start_server(self._handle, self.host, self.port)
            self.port = self._server.sockets[0].getsockname()[1]
        return self.port

    async def stop(self) -> None:
        """Close the listener and drop every connection (a cable pulled, an instrument switched off)."""
        server, self._server = self._server, None
        if server is not None:
            server.close()
        for writer in list(self._writers):
            writer.close()
        self._writers.clear()
        if server is not None:
            with contextlib.suppress(Exception):
                await asyncio.wait_for(server.wait_closed(), 1.0)

    def track(self, writer: asyncio.StreamWriter) -> None:
        """Count ``writer`` (e.g. an upstream connection) among the connections ``stop()`` drops."""
        self._writers.add(writer)

    async def _handle(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self.track(writer)
        try:
            await self.serve_connection(reader, writer)
        except (ConnectionError, asyncio.IncompleteReadError):
            pass
        except Exception as exc:  # noqa: BLE001 - one bad client must not end the server: log, drop it
            log.warning("%s on port %s: connection dropped after %s: %s", self.name, self.port,
                        type(exc).__name__, exc)
        finally:
            self._writers.discard(writer)
            writer.close()

    async def serve_connection(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        raise NotImplementedError


class TcpInstrumentServer(TcpServer):
    """A serial-line instrument on TCP: the common faults (mute, garbage, partial) plus ``DEVICE_FAULTS``."""

    name = "instrument"
    DEVICE_FAULTS: tuple[str, ...] = ()

    def __init__(self, host: str = "127.0.0.1", port: int = 0, reply_delay_s: float = 0.0):
        super().__init__(host, port)
        self.reply_delay_s = float(reply_delay_s)
        self.requests = 0  # requests answered or swallowed (diagnostics, tests)

    @property
    def faults(self) -> tuple[str, ...]:
        return COMMON_FAULTS + self.DEVICE_FAULTS

    async def reply(self, writer: asyncio.StreamWriter, payload: bytes, garbage: bytes) -> None:
        """Send ``payload`` after the reply delay, transformed by the injected fault."""
        self.requests += 1
        fault = self.fault
        if fault == "mute":
            return
        if self.reply_delay_s > 0:
            await asyncio.sleep(self.reply_delay_s)
        if fault == "garbage":
            payload = garbage
        elif fault == "partial":
            payload = payload[: max(1, len(payload) // 2)]
        writer.write(payload)
        await writer.drain()

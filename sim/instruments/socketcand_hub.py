"""A loopback socketcand server (raw mode) that relays CAN frames between its TCP clients.

python-can's ``socketcand`` interface connects to it like to a real socketcand daemon, so CANopen works across
processes without kernel vcan or multicast (protocols.md §4.2). Protocol (socketcand raw mode):

    hub → client  ``< hi >``                 on connect
    client → hub  ``< open can0 >``          hub → ``< ok >``   (any channel name; clients on the same
    client → hub  ``< rawmode >``            hub → ``< ok >``    channel see each other's frames)
    client → hub  ``< send 181 4 37 6 c8 0 >``   (id hex, dlc, data bytes in hex)
    hub → others  ``< frame 181 1700000000.123456 3706C800 >``  (id, time stamp, contiguous hex data)

A frame is relayed to every other client of the channel, never echoed to its sender (like a CAN controller
without self-reception). Malformed commands get ``< error … >``-free silence: they are counted and dropped.
Fault injection: ``mute`` (drop all frames), ``stop()`` (every client loses its connection).
"""

from __future__ import annotations

import asyncio
import contextlib
import re
import socket
import time

from tcms_daq.sim.instruments.tcp import TcpServer

SEND_RE = re.compile(r"^< send ([0-9A-Fa-f]{1,8}) ([0-9A-Fa-f])((?: [0-9A-Fa-f]{1,2})*) *>$")
FAULTS = ("mute",)
RAWMODE_SETTLE_S = 0.05  # frames reach a new raw-mode client this long after its "< ok >"


class _Client:
    def __init__(self, writer: asyncio.StreamWriter):
        self.writer = writer
        self.channel: str | None = None
        self.raw = False


class SocketcandHub(TcpServer):
    name = "socketcand hub"

    def __init__(self, host: str = "127.0.0.1", port: int = 0):
        super().__init__(host, port)
        self.frames_relayed = 0
        self.malformed = 0
        self._clients: set[_Client] = set()

    @property
    def faults(self) -> tuple[str, ...]:
        return FAULTS

    async def serve_connection(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        client = _Client(writer)
        self._clients.add(client)
        sock = writer.get_extra_info("socket")
        if sock is not None:
            with contextlib.suppress(OSError):
                sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        try:
            writer.write(b"< hi >")
            await writer.drain()
            buffer = ""
            while data := await reader.read(4096):
                buffer += data.decode("ascii", errors="replace")
                while ">" in buffer:
                    end = buffer.index(">") + 1
                    start = buffer.find("<")
                    message, buffer = buffer[start:end] if 0 <= start < end else "", buffer[end:]
                    await self._command(client, message.strip())
                if len(buffer) > 1000:
                    buffer = ""
                    self.malformed += 1
        finally:
            self._clients.discard(client)

    async def _command(self, client: _Client, message: str) -> None:
        if message.startswith("< open ") and message.endswith(" >"):
            client.channel = message[7:-2].strip()
            client.writer.write(b"< ok >")
        elif message == "< rawmode >" and client.channel is not None:
            client.writer.write(b"< ok >")
            await client.writer.drain()
            # python-can's client reads the handshake's "< ok >" with one recv() and wants nothing after it: frames
            # relayed right away can arrive in the same read on a busy bus ("Expected '< ok >' got: '< ok >< frame
            # …'"). The client is served frames a moment later, once it has read its "< ok >".
            await asyncio.sleep(RAWMODE_SETTLE_S)
            client.raw = True
        elif message.startswith("< send ") and client.raw:
            self._relay(client, message)
        else:
            self.malformed += 1

    def _relay(self, sender: _Client, message: str) -> None:
        match = SEND_RE.match(message)
        if match is None:
            self.malformed += 1
            return
        can_id, dlc, data_text = match.group(1), int(match.group(2), 16), match.group(3).split()
        if len(data_text) != dlc or dlc > 8:
            self.malformed += 1
            return
        if self.fault == "mute":
            return
        ident = can_id.upper().zfill(3 if len(can_id) <= 3 else 8)
        data = "".join(f"{int(b, 16):02X}" for b in data_text)
        frame = f"< frame {ident} {time.time():.6f} {data} >".encode("ascii")
        for client in list(self._clients):
            if client is not sender and client.raw and client.channel == sender.channel:
                client.writer.write(frame)
        self.frames_relayed += 1

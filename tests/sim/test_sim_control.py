"""The simulators' control channel (``sim.instruments.control``): one JSON request per line on loopback, one JSON
reply per line, every failure answered and the channel kept up."""

from __future__ import annotations

import asyncio
import json

from tcms_daq.sim.instruments.control import CONTROL_LINE_LIMIT, ControlServer


class Simulators:
    """Records what the channel asks of the simulators (the channel's side of InstrumentSimulators)."""

    def __init__(self) -> None:
        self.calls: list[tuple[str, str, str | None]] = []

    def inject(self, instrument: str, fault: str | None) -> None:
        if instrument == "nd999":
            raise KeyError(instrument)
        self.calls.append(("inject", instrument, fault))

    def restart(self, instrument: str) -> None:
        self.calls.append(("restart", instrument, None))


async def _exchange(lines: list[bytes]) -> tuple[list[dict], list[tuple[str, str, str | None]]]:
    sims = Simulators()
    server = ControlServer(sims)  # type: ignore[arg-type]
    port = await server.start()
    try:
        reader, writer = await asyncio.open_connection("127.0.0.1", port)
        replies = []
        for line in lines:
            writer.write(line)
            await writer.drain()
            replies.append(json.loads(await asyncio.wait_for(reader.readline(), 30.0)))
        writer.close()
        return replies, sims.calls
    finally:
        await server.stop()


def test_requests_are_answered_line_by_line():
    replies, calls = asyncio.run(_exchange([
        b'{"cmd": "inject", "instrument": "nd287", "fault": "encoder_fault"}\n',
        b'{"cmd": "restart", "instrument": "aed"}\n',
        b'{"cmd": "reboot"}\n',
        b'{"cmd": "inject", "instrument": "nd999"}\n',
        b"not json\n",
        b'{"cmd": "inject", "instrument": "aed", "fault": null}\n',
    ]))
    assert [r["ok"] for r in replies] == [True, True, False, False, False, True]
    assert "unknown command 'reboot' (inject, restart, status)" in replies[2]["error"]
    assert replies[3]["error"].startswith("KeyError") and replies[4]["error"].startswith("JSONDecodeError")
    assert calls == [("inject", "nd287", "encoder_fault"), ("restart", "aed", None), ("inject", "aed", None)]


def test_an_overlong_line_is_answered_and_the_connection_closed():
    replies, calls = asyncio.run(_exchange([b"x" * (CONTROL_LINE_LIMIT + 10) + b"\n"]))
    assert replies[0]["ok"] is False and "longer than" in replies[0]["error"] and calls == []

"""The simulators' control channel (``tcms sim serve --control-port``): fault injection, restarts and status for
tests, one JSON object per line on loopback, each answered by one JSON line:
``{"cmd": "inject", "instrument": "nd287", "fault": "encoder_fault"}`` (instruments: nd287, aed, modbus, socketcand,
canopen, drive — a drive fault is an EMCY code such as 8976 = 0x2310), ``{"cmd": "restart", "instrument": "aed"}``,
``{"cmd": "status"}``."""

from __future__ import annotations

import asyncio
import json
from typing import Any

from tcms_daq.sim.instruments.serve import InstrumentSimulators
from tcms_daq.sim.instruments.tcp import TcpServer

CONTROL_LINE_LIMIT = 2**16  # asyncio's default stream limit: one JSON request per line stays far below it


class ControlServer(TcpServer):
    """Line-based JSON control channel (fault injection, restarts, status) on the simulators' event loop."""

    name = "control channel"

    def __init__(self, sims: InstrumentSimulators, host: str = "127.0.0.1", port: int = 0):
        super().__init__(host, port)
        self.sims = sims

    async def serve_connection(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        while True:
            try:
                line = await reader.readline()
            except ValueError:  # asyncio's LimitOverrunError, wrapped: a line beyond the stream limit
                reply = {"ok": False, "error": f"request line longer than {CONTROL_LINE_LIMIT} bytes: "
                         "connection closed"}
                writer.write((json.dumps(reply) + "\n").encode())
                await writer.drain()
                return
            if not line:
                return
            try:
                reply = await asyncio.to_thread(self.execute, json.loads(line))
            except Exception as exc:  # noqa: BLE001 - every failure is answered, the channel stays up
                reply = {"ok": False, "error": f"{type(exc).__name__}: {exc}"}
            writer.write((json.dumps(reply) + "\n").encode())
            await writer.drain()

    def execute(self, request: dict[str, Any]) -> dict[str, Any]:
        cmd = request.get("cmd")
        sims = self.sims
        if cmd == "inject":
            sims.inject(request["instrument"], request.get("fault"))
            return {"ok": True}
        if cmd == "restart":
            sims.restart(request["instrument"])  # runs in a worker thread; server restarts hop onto the loop
            return {"ok": True}
        if cmd == "status":
            latest = sims.physics.latest()
            drive = sims.drive
            return {
                "ok": True,
                "time_s": latest.time_s,
                "torque_nm": latest.torque_nm,
                "angle_arcsec": latest.angle_arcsec,
                "applied_torque_nm": latest.applied_torque_nm,
                "drive": None if drive is None else {
                    "state": drive.state.label, "statusword": drive.statusword(), "error_code": drive.error_code,
                    "comm_timeout_ms": drive.comm_timeout_ms, "abort_connection_option": drive.abort_connection_option,
                },
                "input_drive": None if sims.input_drive is None else {
                    "state": sims.input_drive.state.label, "error_code": sims.input_drive.error_code,
                    "velocity_deg_per_s": sims.input_drive.velocity_deg_per_s(),
                },
                "watchdog_reactions": sims.watchdog_reactions(),
            }
        raise ValueError(f"unknown command {cmd!r} (inject, restart, status)")

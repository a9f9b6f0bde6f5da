"""Soak of the CANopen heartbeat under load (issue 22: spurious 0x8130 faults on a loaded machine).

Starts `tcms sim serve` (speed 1) in its own process, connects the CANopen loader with its packaged defaults (drive
heartbeat 100 ms, master heartbeat 100 ms, the drive's consumer derived: 1 s), enables the drive at zero torque and
polls its status as the acquisition loop does (every 50 ms) for ``--duration`` seconds, optionally beside
``--hogs`` CPU hogs (`yes > /dev/null`). Prints one JSON line: polls, failed polls, the drive's consumer reactions
(0x8130), late drive heartbeats the driver waited out, reconnects, the machine's load average.

    .venv/bin/python scripts/heartbeat_soak.py --duration 180 --hogs 2
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import time

from tcms_daq.drivers.base import InstrumentError
from tcms_daq.drivers.cia402_canopen import CiA402Canopen
from tcms_daq.drivers.testing import driver_for
from tcms_daq.sim.instruments.child import start_simulators, stop_process


def _control(port: int, **request) -> dict:
    with socket.create_connection(("127.0.0.1", port), timeout=30) as sock:
        sock.sendall((json.dumps(request) + "\n").encode())
        return json.loads(sock.makefile().readline())


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--duration", type=float, default=180.0, help="real seconds of polling (default 180)")
    parser.add_argument("--hogs", type=int, default=0, help="CPU hogs (yes > /dev/null) beside it (default 0)")
    args = parser.parse_args()
    hogs = [subprocess.Popen(["yes"], stdout=subprocess.DEVNULL) for _ in range(args.hogs)]
    sim, info = start_simulators("--config", "bench-loopback.toml", "--speed", "1", timeout_s=300)
    polls = failed = 0
    try:
        drive = driver_for(CiA402Canopen, info["urls"]["loader_canopen"])
        drive.connect()
        drive.enable()
        load_before = os.getloadavg()[0]
        end = time.monotonic() + args.duration
        while time.monotonic() < end:
            try:
                drive.status()
                polls += 1
            except InstrumentError:
                failed += 1
            time.sleep(0.05)
        status = _control(info["ports"]["control"], cmd="status")
        result = {"duration_s": args.duration, "hogs": args.hogs, "polls": polls, "failed_polls": failed,
                  "consumer_reactions": len(status["watchdog_reactions"]), "drive_state": status["drive"]["state"],
                  "late_drive_heartbeats": drive.link.late_heartbeats, "reconnects": drive.link.reconnects,
                  "consumer_timeout_ms": drive.drive_consumer_timeout_ms,
                  "load_1min_before": round(load_before, 1), "load_1min_after": round(os.getloadavg()[0], 1)}
        drive.disable()
        drive.close()
    finally:
        stop_process(sim)
        for hog in hogs:
            hog.kill()
            hog.wait()
    print(json.dumps(result))
    return 0 if result["consumer_reactions"] == 0 else 1


if __name__ == "__main__":
    raise SystemExit(main())

"""``tcms sim serve`` as a child process on ephemeral loopback ports, for tests, benchmarks and scripts that need
the simulators in a process of their own (as a user runs them in a second terminal).

``tcms sim serve`` prints one JSON line when its servers listen: ``{"ports": {...}, "urls": {...}}``; the
``urls`` are what a bench config's ``instruments.*.url`` take (``angle``, ``torque``, ``loader_canopen``,
``loader_modbus``).
"""

from __future__ import annotations

import json
import select
import subprocess
import sys
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from typing import Any

EPHEMERAL_PORTS = ("--nd287-port", "0", "--aed-port", "0", "--modbus-port", "0", "--socketcand-port", "0",
                   "--control-port", "0")


def start_simulators(*args: str, command: Sequence[str] = (sys.executable, "-m", "tcms_daq.cli"),
                     cwd: Any = None, env: dict[str, str] | None = None,
                     timeout_s: float = 30.0) -> tuple[subprocess.Popen[str], dict[str, Any]]:
    """Start ``<command> sim serve <args>`` on ephemeral ports and return the process and its JSON line (ports
    and urls). RuntimeError with the simulator's error output when it does not report its ports in
    ``timeout_s``."""
    proc = subprocess.Popen([*command, "sim", "serve", *EPHEMERAL_PORTS, *args], cwd=cwd, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert proc.stdout is not None and proc.stderr is not None
    ready, _, _ = select.select([proc.stdout], [], [], timeout_s)
    line = proc.stdout.readline() if ready else ""
    if not line:
        stop_process(proc)
        raise RuntimeError(f"tcms sim serve did not report its ports within {timeout_s:g} s: "
                           f"{proc.stderr.read()[-2000:]}")
    return proc, json.loads(line)


def stop_process(proc: subprocess.Popen[str], timeout_s: float = 15.0) -> None:
    """SIGTERM, then SIGKILL when it has not ended within ``timeout_s``."""
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(10)


@contextmanager
def running_simulators(*args: str, **options: Any) -> Iterator[dict[str, Any]]:
    """:func:`start_simulators` for the duration of a ``with`` block; yields the JSON line (ports, urls)."""
    proc, info = start_simulators(*args, **options)
    try:
        yield info
    finally:
        stop_process(proc)

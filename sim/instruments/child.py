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
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from typing import Any

SERVERS = ("nd287", "aed", "modbus", "socketcand", "control")  # each has a --<name>-port option


def start_simulators(*args: str, ports: Mapping[str, int] | None = None,
                     command: Sequence[str] = (sys.executable, "-m", "tcms_daq.cli"), cwd: Any = None,
                     env: dict[str, str] | None = None,
                     timeout_s: float = 30.0) -> tuple[subprocess.Popen[str], dict[str, Any]]:
    """Start ``<command> sim serve <args>`` and return the process and its JSON line (ports and urls). Every
    server listens on an ephemeral port unless ``ports`` names one (e.g. to start the simulators again where
    a service expects them). RuntimeError with the simulator's error output when it does not report its ports
    in ``timeout_s``."""
    chosen = {name: 0 for name in SERVERS} | dict(ports or {})
    port_args = [arg for name, port in chosen.items() for arg in (f"--{name}-port", str(port))]
    proc = subprocess.Popen([*command, "sim", "serve", *port_args, *args], cwd=cwd, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert proc.stdout is not None and proc.stderr is not None
    ready, _, _ = select.select([proc.stdout], [], [], timeout_s)
    line = proc.stdout.readline() if ready else ""
    if not line:
        stop_process(proc)
        raise RuntimeError(f"tcms sim serve did not report its ports within {timeout_s:g} s: "
                           f"{proc.stderr.read()[-2000:]}")
    return proc, json.loads(line)


def stop_process(proc: subprocess.Popen[str], timeout_s: float = 20.0) -> None:
    """SIGTERM (``tcms serve`` aborts a running test and ramps the bench down first), then SIGKILL when it has not
    ended within ``timeout_s``."""
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

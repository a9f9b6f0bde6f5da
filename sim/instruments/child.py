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
import time
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from typing import Any

#: each has a --<name>-port option (underscores as hyphens); the second axis's are used with --second-axis
SERVERS = ("nd287", "aed", "modbus", "socketcand", "control", "input_aed", "nd287_coupled", "counter")


READY_CEILING_S = 300.0  # a generous ceiling: the wait ends when the child reports its ports or exits


def start_simulators(*args: str, ports: Mapping[str, int] | None = None,
                     command: Sequence[str] = (sys.executable, "-m", "tcms_daq.cli"), cwd: Any = None,
                     env: dict[str, str] | None = None,
                     timeout_s: float = READY_CEILING_S) -> tuple[subprocess.Popen[str], dict[str, Any]]:
    """Start ``<command> sim serve <args>`` and return the process and its JSON line (ports and urls). Every
    server listens on an ephemeral port unless ``ports`` names one (e.g. to start the simulators again where
    a service expects them). Waits for what it needs: the JSON line (the child's readiness), or the child's end;
    ``timeout_s`` is only a ceiling for a child that hangs (a loaded machine takes long to import and bind).
    RuntimeError with the simulator's error output when it exits or hangs without reporting its ports."""
    chosen = {name: 0 for name in SERVERS} | dict(ports or {})
    port_args = [arg for name, port in chosen.items() for arg in (f"--{name.replace('_', '-')}-port", str(port))]
    proc = subprocess.Popen([*command, "sim", "serve", *port_args, *args], cwd=cwd, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert proc.stdout is not None and proc.stderr is not None
    deadline = time.monotonic() + timeout_s
    line = ""
    while not line:
        left = deadline - time.monotonic()
        if left <= 0:
            break
        ready, _, _ = select.select([proc.stdout], [], [], min(left, 1.0))
        if ready:
            line = proc.stdout.readline()
            if not line:  # end of file: the child exited before it reported
                break
        elif proc.poll() is not None:
            break
    if not line:
        why = (f"exited with status {proc.poll()}" if proc.poll() is not None
               else f"did not report its ports within the {timeout_s:g} s ceiling")
        stop_process(proc)
        raise RuntimeError(f"tcms sim serve {why}: {proc.stderr.read()[-2000:]}")
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

"""The README's quick tour runs as written, top to bottom, in an empty directory outside the source tree.

The ```bash block under "## A quick tour" is executed line by line with bash (``.venv/bin/`` is this
interpreter's bin directory). A line ending in ``&`` starts a background process (the simulators): the next line
waits until its ports accept connections, as a user in a second terminal would; ``kill %1`` stops it.
"""

from __future__ import annotations

import re
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
BIN = Path(sys.executable).parent
LOOPBACK_PORTS = (4001, 4002, 5020, 29536)  # bench-loopback.toml


def tour_commands() -> list[str]:
    text = (REPO / "README.md").read_text(encoding="utf-8")
    section = text.split("## A quick tour", 1)[1]
    block = re.search(r"```bash\n(.*?)```", section, re.S)
    assert block, "README: no bash block under '## A quick tour'"
    lines = [ln.split("  #")[0].strip() for ln in block.group(1).splitlines()]
    return [ln for ln in lines if ln and not ln.startswith("#")]


def _ports_open(ports) -> bool:
    for port in ports:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=0.5).close()
        except OSError:
            return False
    return True


@pytest.mark.slow
def test_quick_tour_runs_as_written(tmp_path):
    commands = tour_commands()
    assert any("tcms examples" in c for c in commands) and any(c.endswith("&") for c in commands)
    background: subprocess.Popen | None = None
    try:
        for command in commands:
            line = command.replace(".venv/bin/", f"{BIN}/")
            if line.endswith("&"):
                assert background is None, "one background process at a time"
                background = subprocess.Popen(["bash", "-c", f"exec {line[:-1]}"], cwd=tmp_path,
                                              stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
                deadline = time.monotonic() + 60
                while not _ports_open(LOOPBACK_PORTS):
                    assert background.poll() is None, f"{command}: exited: {background.stderr.read()}"
                    assert time.monotonic() < deadline, f"{command}: ports {LOOPBACK_PORTS} not open in 60 s"
                    time.sleep(0.2)
                continue
            if line == "kill %1":
                assert background is not None, "kill %1 without a background process"
                background.terminate()
                background.wait(30)
                background = None
                continue
            proc = subprocess.run(["bash", "-c", line], cwd=tmp_path, capture_output=True, text=True, timeout=600)
            assert proc.returncode == 0, f"$ {command}\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
        assert (tmp_path / "report" / "report.html").is_file() and (tmp_path / "comp.toml").is_file()
    finally:
        if background is not None:
            background.kill()
            background.wait(10)

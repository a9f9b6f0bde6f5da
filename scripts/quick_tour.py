"""Run the README's quick tour as written: the ```bash block under "## A quick tour", line by line with bash, in
an empty directory, with an installed ``tcms`` (and its ``python``) first on PATH.

    python scripts/quick_tour.py BIN_DIR [--workdir DIR]

BIN_DIR holds the ``tcms`` and ``python`` to use (a venv's ``bin``; ``tests/docs/test_quick_tour.py`` passes this
interpreter's, ``scripts/wheel_smoke.py`` the fresh venv's the wheel went into). A line ending in ``&`` starts a
background process (the simulators); ``kill %1`` stops it. Exits non-zero naming the first line that failed.
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


class TourFailed(Exception):
    """A line of the tour failed: the message names it with its output."""


def tour_commands(readme: Path = REPO / "README.md") -> list[str]:
    """The tour's command lines (comments and blank lines dropped)."""
    section = readme.read_text(encoding="utf-8").split("## A quick tour", 1)[1]
    block = re.search(r"```bash\n(.*?)```", section, re.S)
    if not block:
        raise TourFailed("README: no bash block under '## A quick tour'")
    lines = [ln.split("  #")[0].strip() for ln in block.group(1).splitlines()]
    return [ln for ln in lines if ln and not ln.startswith("#")]


def run_tour(bin_dir: Path, workdir: Path, commands: list[str] | None = None, timeout_s: float = 600.0) -> None:
    """Each line in ``workdir`` with ``bin_dir`` first on PATH; TourFailed at the first failing line."""
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    env["PATH"] = f"{bin_dir}{os.pathsep}{env.get('PATH', '')}"
    background: subprocess.Popen[str] | None = None
    try:
        for command in commands if commands is not None else tour_commands():
            print(f"tour$ {command}", flush=True)
            if command.endswith("&"):
                if background is not None:
                    raise TourFailed(f"{command}: one background process at a time")
                background = subprocess.Popen(["bash", "-c", f"exec {command[:-1]}"], cwd=workdir, env=env,
                                              stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
                continue
            if command == "kill %1":
                if background is None:
                    raise TourFailed("kill %1 without a background process")
                background.terminate()
                background.wait(30)
                background = None
                continue
            proc = subprocess.run(["bash", "-c", command], cwd=workdir, env=env, capture_output=True, text=True,
                                  timeout=timeout_s)
            if proc.returncode != 0:
                behind = ""
                if background is not None and background.poll() is not None:
                    behind = f"\n(the background process had exited: {background.stderr.read()[-2000:]})"
                raise TourFailed(f"$ {command}\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}{behind}")
    finally:
        if background is not None:
            background.kill()
            background.wait(10)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("bin_dir", type=Path, help="the bin directory of the installation to use")
    parser.add_argument("--workdir", type=Path, help="run in this (empty) directory (default: a temporary one)")
    args = parser.parse_args()
    workdir = args.workdir or Path(tempfile.mkdtemp(prefix="tcms-tour-"))
    workdir.mkdir(parents=True, exist_ok=True)
    try:
        run_tour(args.bin_dir.resolve(), workdir)
    except TourFailed as exc:
        print(f"quick tour: FAILED: {exc}", file=sys.stderr)
        return 1
    print(f"quick tour: every line ran in {workdir}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

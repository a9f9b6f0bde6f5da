"""A throwaway PostgreSQL server of its own (tests, benchmarks, trying the fleet without a database server).

Debian's ``postgresql`` binaries (``scripts/setup`` installs them): ``initdb`` in a temporary directory, run as the
``postgres`` user when the caller is root (PostgreSQL refuses root), listening on 127.0.0.1 on a free port and on
a unix socket in that directory only; trust authentication for the superuser ``postgres``. ``stop()`` removes it.
"""

from __future__ import annotations

import glob
import os
import shutil
import socket
import subprocess
import tempfile
from pathlib import Path


def pg_bin_dir() -> Path | None:
    found = shutil.which("initdb")
    if found and shutil.which("pg_ctl"):
        return Path(found).resolve().parent
    candidates = sorted(glob.glob("/usr/lib/postgresql/*/bin/initdb"), key=lambda p: int(p.split("/")[4]))
    return Path(candidates[-1]).parent if candidates else None


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class ThrowawayPostgres:
    """A PostgreSQL server of its own in a temporary directory (trust auth, superuser ``postgres``)."""

    def __init__(self, bin_dir: Path, durable: bool = False, settings: dict[str, str] | None = None):
        """``durable``: fsync and full-page writes on (a benchmark's realistic server); off by default (tests kill
        the service, never the database server, so they need no crash safety of the server's own files).
        ``settings``: more server settings (``{"shared_buffers": "256MB"}``)."""
        self.bin_dir = bin_dir
        self.durable = durable
        self.settings = {"shared_buffers": "32MB", **(settings or {})}
        self.root = Path(tempfile.mkdtemp(prefix="tcms-pg-"))
        self.data = self.root / "data"
        self.log = self.root / "server.log"
        self.port = 0
        self._as_postgres: list[str] = []
        if os.geteuid() == 0:
            shutil.chown(self.root, "postgres", "postgres")
            self._as_postgres = ["runuser", "-u", "postgres", "--"]

    def _run(self, *args: str, timeout_s: float = 120.0) -> None:
        proc = subprocess.run([*self._as_postgres, *args], capture_output=True, text=True, timeout=timeout_s)
        if proc.returncode != 0:
            log = self.log.read_text(errors="replace")[-2000:] if self.log.exists() else ""
            raise RuntimeError(f"{args[0]} failed ({proc.returncode}): {proc.stderr.strip()} {log}")

    def start(self) -> None:
        self._run(str(self.bin_dir / "initdb"), "-D", str(self.data), "-U", "postgres", "--auth=trust",
                  "-E", "UTF8", "--no-sync", "--no-instructions")
        for attempt in range(3):
            self.port = _free_port()
            safety = "" if self.durable else " -c fsync=off -c full_page_writes=off"
            extra = "".join(f" -c {key}={value}" for key, value in self.settings.items())
            options = (f"-c listen_addresses=127.0.0.1 -c port={self.port} -c unix_socket_directories={self.root} "
                       f"-c max_connections=200{extra}{safety}")
            try:
                self._run(str(self.bin_dir / "pg_ctl"), "-D", str(self.data), "-l", str(self.log), "-o", options,
                          "-w", "-t", "60", "start")
                return
            except RuntimeError:
                if attempt == 2:
                    raise

    def url(self, database: str = "postgres") -> str:
        return f"postgresql://postgres@127.0.0.1:{self.port}/{database}"

    def stop(self) -> None:
        try:
            self._run(str(self.bin_dir / "pg_ctl"), "-D", str(self.data), "-m", "immediate", "-w", "stop",
                      timeout_s=60)
        except (RuntimeError, subprocess.TimeoutExpired):
            pass
        shutil.rmtree(self.root, ignore_errors=True)

    def server_pids(self) -> list[int]:
        """The postmaster and its children (backends, background workers), for CPU accounting."""
        try:
            postmaster = int((self.data / "postmaster.pid").read_text().split()[0])
        except (OSError, ValueError, IndexError):
            return []
        pids = [postmaster]
        for stat in glob.glob("/proc/[0-9]*/stat"):
            try:
                fields = Path(stat).read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(fields[1]) == postmaster:
                pids.append(int(Path(stat).parent.name))
        return pids

    def __enter__(self) -> ThrowawayPostgres:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

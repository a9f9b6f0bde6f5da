"""Fixtures for every test area: a throwaway PostgreSQL server (session) and a fresh database per test; the reducer
catalogue, the default bench config and its TOML, and TOML files written to a temporary directory.

The server is Debian's ``postgresql`` (``scripts/setup`` installs it): ``initdb`` in a temporary directory, run as
the ``postgres`` user when the tests run as root (PostgreSQL refuses root), listening on 127.0.0.1 on a free port
and on a unix socket in that directory only; stopped and removed at the end. The tests are skipped only on a
machine where setup could not have installed it (no Debian package manager); where it could, a missing server is
an error that says to run setup.
"""

from __future__ import annotations

import shutil
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from tcms_daq.config import load_bench_config, load_reducer_catalogue, packaged_config_dir
from tcms_daq.store.pgserver import ThrowawayPostgres, pg_bin_dir


@pytest.fixture(scope="session")
def postgres_server() -> Iterator[ThrowawayPostgres]:
    bin_dir = pg_bin_dir()
    if bin_dir is None:
        if shutil.which("apt-get"):
            pytest.fail("PostgreSQL server binaries (initdb, pg_ctl) not found: run `bash scripts/setup`, which "
                        "installs Debian's postgresql")
        pytest.skip("no PostgreSQL server binaries and no Debian package manager to install them "
                    "(scripts/setup installs Debian's postgresql)")
    server = ThrowawayPostgres(bin_dir)
    try:
        server.start()
    except BaseException:
        server.stop()
        raise
    yield server
    server.stop()


@pytest.fixture
def postgres_url(postgres_server: ThrowawayPostgres) -> Iterator[str]:
    """The URL of a fresh, empty database on the throwaway server (dropped after the test)."""
    import psycopg

    name = f"tcms_{uuid.uuid4().hex[:12]}"
    with psycopg.connect(postgres_server.url(), autocommit=True) as conn:
        conn.execute(f'CREATE DATABASE "{name}"')  # type: ignore[arg-type]
    yield postgres_server.url(name)
    with psycopg.connect(postgres_server.url(), autocommit=True) as conn:
        conn.execute(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')  # type: ignore[arg-type]


@pytest.fixture(scope="session")
def catalogue():
    return load_reducer_catalogue()


@pytest.fixture(scope="session")
def bench_config():
    return load_bench_config()


@pytest.fixture
def bench_text() -> str:
    return (packaged_config_dir() / "bench-sim.toml").read_text(encoding="utf-8")


@pytest.fixture
def write(tmp_path: Path) -> Callable[[str, str], Path]:
    def _write(name: str, text: str) -> Path:
        path = tmp_path / name
        path.write_text(text, encoding="utf-8")
        return path

    return _write

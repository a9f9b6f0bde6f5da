"""Fixtures for the simulator's tests (``sim/``): the catalogue, the default bench config, and TOML files to
change."""

from __future__ import annotations

from pathlib import Path

import pytest

from tcms_daq.config import load_bench_config, load_reducer_catalogue, packaged_config_dir


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
def write(tmp_path: Path):
    def _write(name: str, text: str) -> Path:
        path = tmp_path / name
        path.write_text(text, encoding="utf-8")
        return path

    return _write

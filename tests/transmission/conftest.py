"""Fixtures for the turning tests (the catalogue, the bench config and ``write`` are the suite's, tests/conftest.py)."""

from __future__ import annotations

import pytest

from tcms_daq.config import packaged_config_dir


@pytest.fixture
def reducers_text() -> str:
    return (packaged_config_dir() / "reducers.toml").read_text(encoding="utf-8")

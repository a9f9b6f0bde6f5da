"""Service test fixtures; the helpers live in ``svc_helpers.py`` (importable: this directory is put on sys.path)."""

from __future__ import annotations

import sys
from collections.abc import Callable
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))

from svc_helpers import TOKEN  # noqa: E402

from tcms_daq.service.app import ServiceSettings  # noqa: E402


@pytest.fixture
def settings_factory(tmp_path: Path) -> Callable[..., ServiceSettings]:
    def make(**kw) -> ServiceSettings:
        kw.setdefault("data_dir", tmp_path / "data")
        kw.setdefault("api_token", TOKEN)
        return ServiceSettings(**kw)

    return make


@pytest.fixture
def sim_config() -> Path:
    """The default simulated bench (config/bench-sim.toml)."""
    from tcms_daq.config.loader import default_bench_config_path

    return default_bench_config_path()

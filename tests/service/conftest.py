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
def sim_config(tmp_path: Path) -> Path:
    """The default simulated bench config; while its compensation file is not in the repo yet, a copy of it
    with the identity compensator (so the service tests do not depend on that file's arrival)."""
    import tomllib

    import tomli_w

    from tcms_daq.config.loader import default_bench_config_path

    path = default_bench_config_path()
    data = tomllib.loads(path.read_text(encoding="utf-8"))
    comp = data.get("bench", {}).get("compensation")
    if comp is None or (path.parent / comp).is_file():
        return path
    data["bench"].pop("compensation")
    data["bench"]["reducers"] = str(path.parent / data["bench"].get("reducers", "reducers.toml"))
    copy = tmp_path / "bench-sim-identity.toml"
    copy.write_text(tomli_w.dumps(data), encoding="utf-8")
    return copy

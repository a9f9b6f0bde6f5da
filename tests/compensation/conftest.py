from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture
def paper_geometry_path() -> Path:
    return REPO / "config" / "geometry-paper.toml"


@pytest.fixture
def repo_root() -> Path:
    return REPO

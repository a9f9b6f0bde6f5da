"""The wheel installs one top-level package: pyproject.toml maps the source folders into ``tcms_daq`` and lists every
package folder, so a folder added on disk and forgotten in the list fails here, not in a user's installation."""

from __future__ import annotations

import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _setuptools() -> dict:
    return tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["tool"]["setuptools"]


def test_every_installed_name_lives_under_tcms_daq():
    config = _setuptools()
    assert all(name == "tcms_daq" or name.startswith("tcms_daq.") for name in config["packages"])
    assert config["package-dir"] == {"tcms_daq": "tcms_daq", "tcms_daq.drivers": "drivers", "tcms_daq.sim": "sim",
                                     "tcms_daq.defaults": "config"}


def test_the_package_list_is_the_folders_on_disk():
    config = _setuptools()
    mapping = sorted(config["package-dir"].items(), key=lambda item: -len(item[0]))

    def folder_of(package: str) -> Path:
        for name, folder in mapping:
            if package == name or package.startswith(name + "."):
                return ROOT / folder / Path(*package[len(name):].lstrip(".").split(".") if package != name else ())
        raise AssertionError(f"{package} is under no package-dir entry")

    listed = {folder_of(p).resolve() for p in config["packages"]}
    on_disk = {path.parent.resolve()
               for folder in config["package-dir"].values()
               for path in (ROOT / folder).rglob("*") if path.is_file() and "__pycache__" not in path.parts}
    assert on_disk - listed == set(), f"folders with files that the wheel would leave out: {sorted(on_disk - listed)}"
    missing = sorted(path for path in listed if not path.is_dir())
    assert not missing, f"listed packages without a folder: {missing}"

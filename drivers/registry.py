"""Driver registry keyed by the names used in bench config (``driver = "nd287"`` …), in the style of python-can's
interface registry: every driver — hardware drivers here, the simulator's in-process instruments in ``sim`` — is
declared as an entry point of the group ``tcms_daq.drivers`` (pyproject ``[project.entry-points]``) and imported
only when a bench names it, so a bench imports only the libraries it uses and ``drivers`` never imports ``sim``.
"""

from __future__ import annotations

from importlib.metadata import entry_points
from typing import Any

from tcms_daq.errors import ConfigError

ENTRY_POINT_GROUP = "tcms_daq.drivers"

_LOADED: dict[str, type] = {}


def names() -> list[str]:
    """The driver names available in this installation."""
    return sorted({ep.name for ep in entry_points(group=ENTRY_POINT_GROUP)})


def driver_class(name: str) -> type:
    """The class registered as ``name``; ConfigError naming the known drivers otherwise."""
    if name not in _LOADED:
        found = [ep for ep in entry_points(group=ENTRY_POINT_GROUP) if ep.name == name]
        if not found:
            raise ConfigError(f"unknown driver {name!r} (known: {', '.join(names()) or 'none'})")
        _LOADED[name] = found[0].load()
    return _LOADED[name]


def create(name: str, **options: Any) -> Any:
    """Instantiate driver ``name`` with keyword options from config (url, timeouts, limits …)."""
    return driver_class(name)(**options)

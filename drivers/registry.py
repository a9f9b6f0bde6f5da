"""Driver registry keyed by the names used in bench config (``driver = "nd287"`` …), in the style of python-can's
interface registry. A driver module registers its class with ``@register("name")``; ``create`` builds one from
config without the caller knowing the class.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import Any

from tcms_daq.errors import ConfigError

_DRIVERS: dict[str, type] = {}

# name -> module that registers it; imported lazily so a bench only imports the libraries it uses.
_KNOWN_MODULES: dict[str, str] = {}


def register(name: str, module: str | None = None) -> Callable[[type], type]:
    def deco(cls: type) -> type:
        _DRIVERS[name] = cls
        return cls

    return deco


def declare(name: str, module: str) -> None:
    """Declare that ``module`` registers driver ``name`` (for lazy import)."""
    _KNOWN_MODULES[name] = module


def names() -> list[str]:
    return sorted(set(_DRIVERS) | set(_KNOWN_MODULES))


def driver_class(name: str) -> type:
    if name not in _DRIVERS and name in _KNOWN_MODULES:
        importlib.import_module(_KNOWN_MODULES[name])
    try:
        return _DRIVERS[name]
    except KeyError:
        raise ConfigError(f"unknown driver {name!r} (known: {', '.join(names()) or 'none'})") from None


def create(name: str, **options: Any):
    """Instantiate driver ``name`` with keyword options from config (url, timeouts, limits …)."""
    return driver_class(name)(**options)


# Real-protocol drivers (issue 4, drivers engineer).
declare("nd287", "drivers.nd287")
declare("aed", "drivers.aed")
declare("cia402-canopen", "drivers.cia402_canopen")
declare("cia402-modbus", "drivers.cia402_modbus")
# In-process drivers over the simulated bench (issue 4, acquisition engineer).
declare("virtual", "drivers.virtual")

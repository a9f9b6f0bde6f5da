"""Driver registry keyed by the names used in bench config (``driver = "nd287"`` …), in the style of python-can's
interface registry: every driver — hardware drivers here, the simulator's in-process instruments in ``sim`` — is
declared as an entry point of the group ``tcms_daq.drivers`` (pyproject ``[project.entry-points]``) and imported
only when a bench names it, so a bench imports only the libraries it uses and ``drivers`` never imports ``sim``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from importlib.metadata import entry_points
from pathlib import Path

from tcms_daq.config.models import BenchConfig
from tcms_daq.errors import ConfigError

ENTRY_POINT_GROUP = "tcms_daq.drivers"

_LOADED: dict[str, type] = {}


@dataclass
class CompositionContext:
    """What the bench composer hands to a driver's ``from_config(kind, options, context)``: the validated bench
    config, the folder its files are relative to, the bench's torque limit (N·m), the real-time clock instruments
    simulated on real time follow, how to build simulated physics from the config (tests inject one), and
    ``shared``: state the instruments of one driver family share (by the family's key)."""

    config: BenchConfig
    config_dir: Path | None = None
    bench_max_torque_nm: float = float("inf")
    real_time_clock: Callable[[], float] | None = None
    physics_factory: Callable[[BenchConfig], object] | None = None
    shared: dict[str, object] = field(default_factory=dict)


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

"""Driver registry keyed by the names used in bench config (``driver = "nd287"`` …), in the style of python-can's
interface registry: every driver — hardware drivers here, the simulator's in-process instruments in ``sim`` — is
declared as an entry point of the group ``tcms_daq.drivers`` (pyproject ``[project.entry-points]``) and imported
only when a bench names it, so a bench imports only the libraries it uses and ``drivers`` never imports ``sim``.
The lookup and each driver's options model are ``tcms_daq.config.drivers`` (the bench config validates the
options when it is read); this module adds what the bench composer hands a driver.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from tcms_daq.config.drivers import ENTRY_POINT_GROUP, driver_class, names, options_model
from tcms_daq.config.models import BenchConfig

__all__ = ["ENTRY_POINT_GROUP", "CompositionContext", "driver_class", "names", "options_model"]


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

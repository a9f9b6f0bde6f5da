"""A bench composed from config: angle source, torque source, loader, clock and compensator.

Each ``[instruments.<kind>]`` table names a registered driver and its options (``url`` and whatever the
driver takes). The composer does not know which drivers are simulated: a driver class may offer
``from_config(kind, options, context)`` to share state with its siblings (the in-process virtual bench does,
so its three instruments drive one physics object); otherwise it is built as ``cls(**options)``.

``connect()`` ends with a safe start (:meth:`Bench.make_safe`): the loader's state and torque are read before
anything else, and a drive found enabled or under torque is ramped to zero and disabled (one left in FAULT is
reported: its torque is off). The report (:class:`SafeStart`) says what was found and done; the service refuses
tests until it is safe.

The clock follows the drivers: when all three instruments expose the same ``time_source`` (an object with
``now_s()`` and ``advance(duration_s)``), the bench runs on that simulated clock; when none does, on real
monotonic time. Mixing the two on one bench is refused.
"""

from __future__ import annotations

import inspect
import logging
import math
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from tcms_daq.acquisition.clock import Clock, MonotonicClock, SimulatedClock
from tcms_daq.acquisition.interlocks import InterlockLimits
from tcms_daq.drivers import registry
from tcms_daq.drivers.base import InstrumentError
from tcms_daq.errors import ConfigError
from tcms_daq.protocols.cia402 import POWERED_STATES

log = logging.getLogger(__name__)
SAFE_TORQUE_SHARE = 0.01  # a drive is "under torque" above this share of the bench's torque limit
DEFAULT_SAFE_TORQUE_NM = 20.0  # … or above this when the bench has no finite limit

KINDS = ("angle", "torque", "loader")
# [instruments.loader] fields of the drive's communication watchdog (config.models.LoaderInstrumentConfig): each goes
# to the loader driver only when it takes it (the CANopen and the Modbus drive take different ones)
WATCHDOG_FIELDS = ("comm_timeout_ms", "abort_connection_option", "master_heartbeat_ms", "drive_consumer_timeout_ms")


def identity_compensator(angle_arcsec: np.ndarray, torque_nm: np.ndarray, time_s: np.ndarray) -> np.ndarray:
    """No correction: θ_c = θ."""
    return angle_arcsec


@dataclass
class SafeStart:
    """What the safe start found on the loader, what it did, and whether the bench is safe now.

    found_*: the state, torque (N·m) and error code read first; actions: what was done, in order; safe: not powered
    and |torque| within ``safe_torque_nm``; message: one line for the log, the event and a 409."""

    found_state: str | None
    found_torque_nm: float | None
    found_error_code: int
    actions: list[str]
    safe: bool
    message: str
    safe_torque_nm: float
    final_state: str | None = None
    final_torque_nm: float | None = None
    at_monotonic_s: float = field(default_factory=time.monotonic)

    def to_dict(self) -> dict[str, Any]:
        return {"found_state": self.found_state, "found_torque_nm": self.found_torque_nm,
                "found_error_code": self.found_error_code, "actions": list(self.actions), "safe": self.safe,
                "message": self.message, "safe_torque_nm": self.safe_torque_nm, "final_state": self.final_state,
                "final_torque_nm": self.final_torque_nm}


def is_safe(state: str, torque_nm: float, safe_torque_nm: float) -> bool:
    """A loader that cannot apply torque and carries none (within ``safe_torque_nm``)."""
    return state not in POWERED_STATES and abs(torque_nm) <= safe_torque_nm


@dataclass
class Bench:
    """The instruments of one bench and how its readings are corrected.

    compensator: an object with ``apply(angle_arcsec, torque_nm, time_s) -> angle_arcsec`` (a
    ``tcms_daq.compensation.Compensator``) or a plain callable with the same signature.
    """

    angle: Any
    torque: Any
    loader: Any
    clock: Clock
    compensator: Any = identity_compensator
    name: str = "bench"
    max_torque_nm: float = math.inf
    description: dict[str, Any] = field(default_factory=dict)
    interlocks: dict[str, Any] = field(default_factory=dict)  # [interlocks] of the config: InterlockLimits fields
    connected: bool = False
    safe_start: SafeStart | None = None  # what connect() found on the loader and did about it

    @property
    def safe_torque_nm(self) -> float:
        """Torque (N·m) above which a loader counts as under torque: 1 % of the bench's limit."""
        if math.isfinite(self.max_torque_nm):
            return SAFE_TORQUE_SHARE * self.max_torque_nm
        return DEFAULT_SAFE_TORQUE_NM

    def compensate(self, angle_arcsec: np.ndarray, torque_nm: np.ndarray, time_s: np.ndarray) -> np.ndarray:
        apply = getattr(self.compensator, "apply", None)
        if apply is not None:
            return apply(angle_arcsec, torque_nm, time_s)
        return self.compensator(angle_arcsec, torque_nm, time_s)

    def instruments(self) -> dict[str, Any]:
        return {"angle": self.angle, "torque": self.torque, "loader": self.loader}

    def set_specimen(self, reducer: Any) -> bool:
        """Tell a simulated bench which reducer is mounted (its physics follows the request); a real bench has
        whatever is mounted and ignores it. True when an instrument took it (``set_specimen`` on a driver)."""
        taken = False
        for drv in self.instruments().values():
            setter = getattr(drv, "set_specimen", None)
            if setter is not None:
                setter(reducer)
                taken = True
        return taken

    def connect(self) -> None:
        """Connect all instruments; on a failure close the ones already open and re-raise."""
        opened = []
        try:
            for drv in self.instruments().values():
                drv.connect()
                opened.append(drv)
        except BaseException:
            for drv in opened:
                try:
                    drv.close()
                except Exception:
                    pass
            raise
        self.connected = True
        self.safe_start = self.make_safe()

    def make_safe(self) -> SafeStart:
        """Safe start: read the loader's state and torque first; one enabled or under torque is ramped to zero
        (the driver's default slope) and disabled, one in FAULT is reported (its torque is off; the next test
        resets it). Logged at WARNING when anything was found, INFO otherwise; never raises for the loader."""
        loader, limit = self.loader, self.safe_torque_nm
        name = getattr(loader, "name", "loader")
        try:
            found = loader.status()
        except InstrumentError as exc:
            report = SafeStart(None, None, 0, [], False, f"safe start: cannot read {name}: {exc}", limit)
            log.error("%s", report.message)
            return report
        fault = f" 0x{found.error_code:04X}" if found.fault else ""
        what = f"{name} found {found.state}{fault} at {found.torque_actual_nm:.1f} N·m"
        actions: list[str] = []
        final = found
        if not is_safe(found.state, found.torque_actual_nm, limit) or found.state in POWERED_STATES:
            try:
                if found.state in POWERED_STATES:
                    loader.set_torque(0.0)
                    actions.append("target torque 0 (ramped)")
                loader.disable()
                actions.append("disabled")
                final = loader.status()
            except InstrumentError as exc:
                actions.append(f"failed: {exc}")
        safe = is_safe(final.state, final.torque_actual_nm, limit)
        if not actions and found.fault:
            message = f"safe start: {what}: safe (torque off; the next test resets the fault)"
        elif not actions:
            message = f"safe start: {what}: safe, nothing to do"
        elif safe:
            message = f"safe start: {what}: brought to {final.state} at {final.torque_actual_nm:.1f} N·m"
        else:
            message = (f"safe start: {what}: NOT safe ({'; '.join(actions)}; now {final.state} at "
                       f"{final.torque_actual_nm:.1f} N·m)")
        report = SafeStart(found.state, found.torque_actual_nm, found.error_code if found.fault else 0, actions,
                           safe, message, limit, final.state, final.torque_actual_nm)
        log.log(logging.WARNING if actions or found.fault or not safe else logging.INFO, "%s", message)
        return report

    def close(self) -> None:
        for drv in self.instruments().values():
            try:
                drv.close()
            except Exception:
                pass
        self.connected = False

    def __enter__(self) -> Bench:
        self.connect()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _section(config: Any, key: str) -> Any:
    if isinstance(config, Mapping):
        return config.get(key)
    return getattr(config, key, None)


def _as_dict(obj: Any) -> dict[str, Any]:
    if obj is None:
        return {}
    if isinstance(obj, Mapping):
        return dict(obj)
    dump = getattr(obj, "model_dump", None)
    if dump is not None:
        return dict(dump())
    return dict(vars(obj))


def load_compensator(path: str | Path) -> Any:
    """The compensator of a compensator or geometry TOML (``tcms_daq.compensation.load_compensator``);
    ConfigError when unusable."""
    from tcms_daq.compensation import load_compensator as load

    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"compensation model {path}: no such file")
    return load(path)


def _accepts(cls: Any, name: str) -> bool:
    try:
        params = inspect.signature(cls).parameters
    except (TypeError, ValueError):
        return False
    return name in params or any(p.kind is p.VAR_KEYWORD for p in params.values())


def _takes(cls: Any, name: str) -> bool:
    """``cls(...)`` has a parameter ``name`` (by name: a driver taking ``**options`` does not take them all)."""
    try:
        return name in inspect.signature(cls).parameters
    except (TypeError, ValueError):
        return False


def compose_bench(config: Any, *, config_dir: str | Path | None = None, speed: float | None = None,
                  physics_factory: Callable[[Any], Any] | None = None, compensator: Any = None) -> Bench:
    """Build a :class:`Bench` (not yet connected) from a bench config (mapping or the core's config model).

    speed: on a simulated clock, simulated seconds per real second (default inf: as fast as possible); on real
    time, the speed of the protocol simulators' physics (default 1; real instruments: 1). Drivers that take a
    ``clock`` get the bench clock's ``now``, so every reading is stamped on the bench's time base.
    physics_factory: builds the simulated physics from the bench config (tests inject one).
    compensator: overrides the ``bench.compensation`` file.
    """
    bench_cfg = _as_dict(_section(config, "bench"))
    instruments = _section(config, "instruments")
    if instruments is None:
        raise ConfigError("bench config: missing [instruments] (angle, torque, loader)")
    max_torque_nm = float(bench_cfg.get("max_torque_nm", math.inf))
    interlocks = _as_dict(_section(config, "interlocks"))
    unknown = sorted(set(interlocks) - set(InterlockLimits.__dataclass_fields__))
    if unknown:
        raise ConfigError(f"bench config: unknown key {unknown[0]!r} in [interlocks] "
                          f"(known: {', '.join(InterlockLimits.__dataclass_fields__)})")
    real_clock = MonotonicClock(1.0 if speed is None or not math.isfinite(speed) else speed)
    context: dict[str, Any] = {
        "config": config,
        "physics_factory": physics_factory,
        "bench_max_torque_nm": max_torque_nm,
        "config_dir": config_dir,
        "real_time_clock": real_clock.now,  # instruments simulated on real time follow this clock
    }
    drivers: dict[str, Any] = {}
    description: dict[str, Any] = {}
    for kind in KINDS:
        opts = _as_dict(_section(instruments, kind))
        if not opts:
            raise ConfigError(f"bench config: missing [instruments.{kind}]")
        driver_name = opts.pop("driver", None)
        opts.pop("calibration", None)  # for the certificate, not the driver
        if not driver_name:
            raise ConfigError(f"bench config: [instruments.{kind}] has no 'driver'")
        opts.pop("uncertainty", None)  # the declared uncertainty of its reading: the evaluation's, not the driver's
        opts = {k: v for k, v in opts.items() if v is not None}
        cls = registry.driver_class(driver_name)
        if kind == "loader":
            opts = {k: v for k, v in opts.items() if k not in WATCHDOG_FIELDS or _takes(cls, k)}
        from_config = getattr(cls, "from_config", None)
        if from_config is None and "clock" not in opts and _accepts(cls, "clock"):
            opts["clock"] = real_clock.now
        try:
            drivers[kind] = from_config(kind, opts, context) if from_config else cls(**opts)
        except TypeError as exc:
            raise ConfigError(f"bench config: [instruments.{kind}] driver {driver_name!r}: {exc}") from None
        description[kind] = {"driver": driver_name, **{k: v for k, v in opts.items() if k != "clock"}}

    sources = [getattr(d, "time_source", None) for d in drivers.values()]
    shared = sources[0]
    if shared is not None and all(s is not None for s in sources):
        if any(s is not shared for s in sources):
            raise ConfigError("bench config: the simulated instruments must share one bench (same url)")
        clock: Clock = SimulatedClock(shared, speed=math.inf if speed is None else speed)
    elif any(s is not None for s in sources):
        raise ConfigError("bench config: cannot mix simulated (virtual) and real instruments on one bench")
    else:
        clock = real_clock

    comp_source = "identity"
    if compensator is None:
        comp_file = bench_cfg.get("compensation")
        if comp_file:
            path = Path(comp_file)
            if not path.is_absolute() and config_dir is not None:
                path = Path(config_dir) / path
            compensator = load_compensator(path)
            comp_source = str(path)
        else:
            compensator = identity_compensator
    else:
        comp_source = type(compensator).__name__
    description["compensation"] = comp_source
    return Bench(drivers["angle"], drivers["torque"], drivers["loader"], clock, compensator,
                 name=str(bench_cfg.get("name", "bench")), max_torque_nm=max_torque_nm, description=description,
                 interlocks=interlocks)


def read_bench_config(path: str | Path) -> Any:
    """A validated bench config from TOML (``tcms_daq.config.load_bench_config``)."""
    from tcms_daq.config import load_bench_config

    return load_bench_config(Path(path))


def bench_from_file(path: str | Path, **kwargs: Any) -> Bench:
    path = Path(path)
    return compose_bench(read_bench_config(path), config_dir=path.parent, **kwargs)

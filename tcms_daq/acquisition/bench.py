"""A bench composed from config: angle source, torque source, loader, clock and compensator.

Each ``[instruments.<kind>]`` table names a registered driver and its options, validated against the driver's
``options_model`` when the config was read (``tcms_daq.config.drivers``). The composer does not know which drivers
are simulated: a driver class may offer ``from_config(kind, options, context)`` to share state with its siblings
(the in-process virtual bench does, so its three instruments drive one physics object); otherwise it is built as
``cls(options, clock=…)`` on the bench's real-time clock.

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
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

import numpy as np

from tcms_daq.acquisition.clock import Clock, MonotonicClock, SimulatedClock
from tcms_daq.compensation import Compensator
from tcms_daq.config.models import (
    BenchConfig,
    InstrumentConfig,
    InterlocksSection,
    ReducerSpec,
)
from tcms_daq.drivers import registry
from tcms_daq.drivers.base import AngleSource, InputDrive, InstrumentError, Loader, TorqueSource
from tcms_daq.errors import ConfigError
from tcms_daq.protocols.cia402 import POWERED_STATES

log = logging.getLogger(__name__)
SAFE_TORQUE_SHARE = 0.01  # a drive is "under torque" above this share of the bench's torque limit
DEFAULT_SAFE_TORQUE_NM = 20.0  # … or above this when the bench has no finite limit

KINDS = ("angle", "torque", "loader")
#: the second axis's instruments, each optional (a bench without them runs the stiffness test as before)
SECOND_AXIS_KINDS = ("input_drive", "input_torque", "input_angle")
#: the methods of each kind's protocol (tcms_daq.drivers.base: AngleSource, TorqueSource, Loader, InputDrive)
METHODS = {"angle": ("connect", "close", "read"), "torque": ("connect", "close", "read", "tare"),
           "loader": ("connect", "close", "enable", "disable", "set_torque", "status", "fault_reset"),
           "input_drive": ("connect", "close", "enable", "disable", "set_velocity", "status", "fault_reset"),
           "input_torque": ("connect", "close", "read", "tare"), "input_angle": ("connect", "close", "read")}


#: a correction of the angle reading: (angle arcsec, torque N·m, time s) -> corrected angle arcsec
AngleCorrection = Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]
#: what corrects a bench's angle readings: a compensator (its ``apply``) or a plain correction
Compensation = Compensator | AngleCorrection


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

    angle: AngleSource
    torque: TorqueSource
    loader: Loader
    clock: Clock
    compensator: Compensation = identity_compensator
    name: str = "bench"
    max_torque_nm: float = math.inf
    description: dict[str, Any] = field(default_factory=dict)
    interlocks: InterlocksSection = field(default_factory=InterlocksSection)  # [interlocks]: limits it replaces
    connected: bool = False
    safe_start: SafeStart | None = None  # what connect() found on the loader and did about it
    # the second axis (optional): the input drive, the input torque channel, the input/output angle pair source
    input_drive: InputDrive | None = None
    input_torque: TorqueSource | None = None
    input_angle: AngleSource | None = None
    input_safe_start: SafeStart | None = None  # what connect() found on the input drive and did about it

    @property
    def safe_torque_nm(self) -> float:
        """Torque (N·m) above which a loader counts as under torque: 1 % of the bench's limit."""
        if math.isfinite(self.max_torque_nm):
            return SAFE_TORQUE_SHARE * self.max_torque_nm
        return DEFAULT_SAFE_TORQUE_NM

    def compensate(self, angle_arcsec: np.ndarray, torque_nm: np.ndarray, time_s: np.ndarray) -> np.ndarray:
        if isinstance(self.compensator, Compensator):
            return self.compensator.apply(angle_arcsec, torque_nm, time_s)
        return self.compensator(angle_arcsec, torque_nm, time_s)

    def instruments(self) -> dict[str, AngleSource | TorqueSource | Loader | InputDrive]:
        found: dict[str, AngleSource | TorqueSource | Loader | InputDrive] = {
            "angle": self.angle, "torque": self.torque, "loader": self.loader}
        for kind in SECOND_AXIS_KINDS:
            drv = getattr(self, kind)
            if drv is not None:
                found[kind] = drv
        return found

    def set_specimen(self, reducer: ReducerSpec) -> bool:
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
        if self.input_drive is not None:
            self.input_safe_start = self.make_input_drive_safe()

    def make_input_drive_safe(self) -> SafeStart:
        """The safe start of the second axis: the input drive's state and velocity are read first; one found enabled
        (turning or not) is ramped to rest and disabled, one in FAULT is reported. ``found_torque_nm`` and
        ``final_torque_nm`` carry nothing here (None): the message says the velocity. Never raises."""
        drive = self.input_drive
        assert drive is not None
        name = getattr(drive, "name", "input drive")
        try:
            found = drive.status()
        except InstrumentError as exc:
            report = SafeStart(None, None, 0, [], False, f"safe start: cannot read {name}: {exc}", 0.0)
            log.error("%s", report.message)
            return report
        what = (f"{name} found {found.state}{f' 0x{found.error_code:04X}' if found.fault else ''} at "
                f"{found.velocity_deg_per_s:.1f} deg/s")
        actions: list[str] = []
        final = found
        if found.state in POWERED_STATES:
            try:
                drive.disable()
                actions.append("velocity 0 (ramped), disabled")
                final = drive.status()
            except InstrumentError as exc:
                actions.append(f"failed: {exc}")
        safe = final.state not in POWERED_STATES
        if not actions:
            message = f"safe start: {what}: safe{' (stopped; the next test resets the fault)' if found.fault else ''}"
        elif safe:
            message = f"safe start: {what}: brought to {final.state} at {final.velocity_deg_per_s:.1f} deg/s"
        else:
            message = f"safe start: {what}: NOT safe ({'; '.join(actions)}; now {final.state})"
        report = SafeStart(found.state, None, found.error_code if found.fault else 0, actions, safe, message, 0.0,
                           final.state, None)
        log.log(logging.WARNING if actions or found.fault or not safe else logging.INFO, "%s", message)
        return report

    def stop_input_drive(self) -> None:
        """Bring the input drive to rest and disable it if it is powered (every exit path of a method that turned
        it); logs and swallows a failure (its own watchdog stops a drive whose link is gone)."""
        drive = self.input_drive
        if drive is None:
            return
        try:
            if drive.status().state in POWERED_STATES:
                drive.disable()
        except InstrumentError as exc:
            log.error("%s: could not stop the input drive: %s", getattr(drive, "name", "input drive"), exc)

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
        if self.connected:
            self.stop_input_drive()
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


def load_compensator(path: str | Path) -> Compensator:
    """The compensator of a compensator or geometry TOML (``tcms_daq.compensation.load_compensator``);
    ConfigError when unusable."""
    from tcms_daq.compensation import load_compensator as load

    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"compensation model {path}: no such file")
    return load(path)


def compose_bench(config: BenchConfig, *, config_dir: str | Path | None = None, speed: float | None = None,
                  physics_factory: Callable[[BenchConfig], object] | None = None,
                  compensator: Compensation | None = None) -> Bench:
    """Build a :class:`Bench` (not yet connected) from a validated bench config.

    speed: on a simulated clock, simulated seconds per real second (default inf: as fast as possible); on real
    time, the speed of the protocol simulators' physics (default 1; real instruments: 1). Drivers that take a
    ``clock`` get the bench clock's ``now``, so every reading is stamped on the bench's time base.
    physics_factory: builds the simulated physics from the bench config (tests inject one).
    compensator: overrides the ``bench.compensation`` file.
    """
    section = config.bench
    real_clock = MonotonicClock(1.0 if speed is None or not math.isfinite(speed) else speed)
    context = registry.CompositionContext(
        config=config, config_dir=Path(config_dir) if config_dir is not None else None,
        bench_max_torque_nm=section.max_torque_nm, real_time_clock=real_clock.now,
        physics_factory=physics_factory)
    drivers: dict[str, object] = {}
    description: dict[str, Any] = {}
    for kind in (*KINDS, *SECOND_AXIS_KINDS):
        instrument: InstrumentConfig | None = getattr(config.instruments, kind)
        if instrument is None:
            continue
        driver_name = instrument.driver
        cls = registry.driver_class(driver_name)
        options = instrument.options
        if not isinstance(options, registry.options_model(driver_name)):
            raise ConfigError(f"bench config: [instruments.{kind}] driver {driver_name!r}: options of another driver "
                              f"({type(options).__name__}); the config was not validated for this driver")
        from_config = getattr(cls, "from_config", None)
        if from_config is not None:
            drivers[kind] = from_config(kind, options, context)
        else:
            drivers[kind] = cls(options, clock=real_clock.now)
        missing = [m for m in METHODS[kind] if not callable(inspect.getattr_static(drivers[kind], m, None))]
        if missing:
            raise ConfigError(f"bench config: [instruments.{kind}] driver {driver_name!r} is not a {kind} driver "
                              f"(no {', '.join(missing)})")
        description[kind] = {"driver": driver_name, **options.model_dump(mode="json", exclude_defaults=True),
                             "url": options.url}

    sources = [getattr(drv, "time_source", None) for drv in drivers.values()]
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
        if section.compensation:
            path = Path(section.compensation)
            if not path.is_absolute() and config_dir is not None:
                path = Path(config_dir) / path
            compensator = load_compensator(path)
            comp_source = str(path)
        else:
            compensator = identity_compensator
    else:
        comp_source = type(compensator).__name__
    description["compensation"] = comp_source
    return Bench(cast(AngleSource, drivers["angle"]), cast(TorqueSource, drivers["torque"]),
                 cast(Loader, drivers["loader"]), clock, compensator,
                 name=section.name, max_torque_nm=section.max_torque_nm, description=description,
                 interlocks=config.interlocks, input_drive=cast("InputDrive | None", drivers.get("input_drive")),
                 input_torque=cast("TorqueSource | None", drivers.get("input_torque")),
                 input_angle=cast("AngleSource | None", drivers.get("input_angle")))


def read_bench_config(path: str | Path) -> BenchConfig:
    """A validated bench config from TOML (``tcms_daq.config.load_bench_config``)."""
    from tcms_daq.config import load_bench_config

    return load_bench_config(Path(path))


def bench_from_file(path: str | Path, *, speed: float | None = None,
                    physics_factory: Callable[[BenchConfig], object] | None = None,
                    compensator: Compensation | None = None) -> Bench:
    """The bench of a config file (files it names relative to it)."""
    path = Path(path)
    return compose_bench(read_bench_config(path), config_dir=path.parent, speed=speed,
                         physics_factory=physics_factory, compensator=compensator)

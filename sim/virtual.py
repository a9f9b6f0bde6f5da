"""In-process drivers over one simulated bench (``virtual://name``).

A :class:`VirtualBench` wraps one physics object with the ``SimulatedBench`` contract (``set_drive_enabled``,
``set_torque_target(target_nm, slope_nm_per_s)``, ``advance(duration_s) -> Samples``, ``now_s``) and its
simulated clock. Three drivers share it: an angle source, a torque source and a loader. Time only moves when
someone calls :meth:`VirtualBench.advance` (the acquisition's simulated clock does, in its ``sleep``); every
advance appends the high-rate samples the physics produced to per-channel buffers, and ``read()`` drains them.
Samples are stamped with the simulated clock, i.e. at the "driver".

On the real-time clock (``virtual://sim?clock=real-time``) the physics follows the bench's real-time clock
instead: every reading and command first runs it up to the clock's present (:meth:`VirtualBench.catch_up`), and
the samples are stamped on that clock. The drivers then look like real instruments with a buffer (no simulated
time source), so the bench runs on the threaded scheduler — its reader threads, coordinator and status poller —
at the simulated sample rate, with no protocol between (``benchmarks/live_pipeline.py`` measures that path).

Fault hooks (:class:`VirtualFaults`) let tests trip every interlock without a protocol simulator: encoder
fault, muted channels (stale data), torque offset spike, drive fault (with an error code, as an EMCY would
carry) and a lost loader; for the second axis an input drive fault, its lost link and muted input channels.

The second axis (``[sim.transmission] enabled``): the turning unit (``sim.instruments.drivetrain.UnitDriveTrain``,
the protocol simulators' drivetrain too) turns the output of the simulated bench (its rotation goes into the true
angle before the measuring chain, so the output encoder reads it as it reads the twist); three more drivers read
and command it: the input drive (:class:`VirtualInputDrive`, profile velocity), the input torque channel
(:class:`VirtualInputTorque`) and the angle pair source (:class:`VirtualAnglePair`: the output and input encoders
latched together at the bench's samples).

Sign convention: positive torque twists the output towards positive angle; angle in arcsec, torque in N·m.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol, runtime_checkable
from urllib.parse import parse_qs, urlparse

import numpy as np
from pydantic import Field
from tcms_daq.drivers.base import (
    INPUT_ANGLE_COLUMN,
    Batch,
    CommandRejected,
    DeviceFault,
    Disconnected,
    InputDriveStatus,
    LoaderStatus,
    concat_common_columns,
)
from tcms_daq.drivers.registry import CompositionContext
from tcms_daq.sim.bench import SimulatedBench
from tcms_daq.sim.instruments.drivetrain import UnitDriveTrain

from tcms_daq.config.models import BenchConfig, DriverOptions, SimTransmission
from tcms_daq.errors import ConfigError
from tcms_daq.samples import Samples
from tcms_daq.units import ARCSEC_PER_REV

# Bound on buffered samples per channel when nobody reads (oldest dropped): 10 min at 1 kHz.
MAX_BUFFERED_SAMPLES = 600_000
# Drive error code the virtual loader reports for an injected fault without a code (CiA 301 "generic error").
GENERIC_DRIVE_FAULT = 0x1000


@dataclass
class VirtualFaults:
    """Fault injection switches shared by the three virtual drivers of one bench."""

    encoder_fault: bool = False  # angle read raises DeviceFault (ND 287 shows '?')
    angle_muted: bool = False  # angle read returns nothing (stale data)
    torque_muted: bool = False  # torque read returns nothing
    torque_offset_nm: float = 0.0  # added to every torque reading (a sensor jump)
    drive_fault_code: int = 0  # != 0: drive in FAULT with this error code (as an EMCY carries)
    loader_lost: bool = False  # loader calls raise Disconnected
    # the second axis
    input_drive_fault_code: int = 0  # != 0: the input drive in FAULT with this code (the shaft braked at once)
    input_drive_lost: bool = False  # input drive calls raise Disconnected (its watchdog faults it 0x8130)
    input_angle_muted: bool = False  # the angle pair source returns nothing
    input_torque_muted: bool = False


@dataclass(frozen=True)
class ExtraBatch(Batch):
    """A batch with extra per-reading columns (the simulation's ground truth: ``applied_torque_nm``,
    ``true_angle_arcsec`` …); the acquisition carries them along into the recorded samples."""

    extra: dict[str, np.ndarray] = field(default_factory=dict)


class _ChannelBuffer:
    """Append-only time/value(/extra) buffer drained by ``take``; bounded, drops the oldest."""

    def __init__(self) -> None:
        self._time: list[np.ndarray] = []
        self._value: list[np.ndarray] = []
        self._extra: list[dict[str, np.ndarray]] = []
        self._count = 0
        self.dropped = 0

    def append(self, time_s: np.ndarray, value: np.ndarray, extra: dict[str, np.ndarray] | None = None) -> None:
        if len(time_s) == 0:
            return
        self._time.append(np.asarray(time_s, dtype=float))
        self._value.append(np.asarray(value, dtype=float))
        self._extra.append(dict(extra or {}))
        self._count += len(time_s)
        while self._count > MAX_BUFFERED_SAMPLES and len(self._time) > 1:
            self._count -= len(self._time[0])
            self.dropped += len(self._time[0])
            del self._time[0], self._value[0], self._extra[0]

    def take(self) -> Batch:
        if not self._time:
            return Batch.empty()
        out = ExtraBatch(np.concatenate(self._time), np.concatenate(self._value),
                         concat_common_columns(self._extra))
        self._time.clear()
        self._value.clear()
        self._extra.clear()
        self._count = 0
        return out

    def clear(self) -> None:
        self.take()


INPUT_RAMP_STEP_S = 0.002  # the in-process input drive's ramp steps (as the protocol simulator's 2 ms ticks)


class InputDriveModel:
    """The in-process input drive's state (CiA 402 profile velocity, as ``sim.instruments.drive402``'s
    VelocityDrive402Model behaves): OPERATION ENABLED ramps the velocity toward its target at the profile
    acceleration; a disable ramps to rest, then leaves OPERATION ENABLED (as the driver's disable does); a fault or
    a lost link brakes the shaft at once (velocity 0) and leaves the drive in FAULT."""

    def __init__(self) -> None:
        self.state = "SWITCH ON DISABLED"
        self.error_code = 0
        self.velocity_deg_per_s = 0.0
        self.target_deg_per_s = 0.0
        self.acceleration_deg_per_s2 = 36000.0
        self.disable_pending = False

    @property
    def ramping(self) -> bool:
        return self.velocity_deg_per_s != self.target_deg_per_s

    def ramp(self, dt_s: float) -> None:
        """The velocity after ``dt_s`` of ramping (at the start of that step, as a drive's tick commands it)."""
        if self.state != "OPERATION ENABLED":
            self.velocity_deg_per_s = self.target_deg_per_s = 0.0
            return
        step = self.acceleration_deg_per_s2 * dt_s
        gap = self.target_deg_per_s - self.velocity_deg_per_s
        self.velocity_deg_per_s = self.target_deg_per_s if abs(gap) <= step else (
            self.velocity_deg_per_s + math.copysign(step, gap))
        if self.disable_pending and self.velocity_deg_per_s == 0.0:
            self.state, self.disable_pending = "SWITCH ON DISABLED", False

    def brake(self, state: str, code: int = 0) -> None:
        self.state, self.error_code = state, int(code)
        self.velocity_deg_per_s = self.target_deg_per_s = 0.0
        self.disable_pending = False


@runtime_checkable
class BenchPhysics(Protocol):
    """What a virtual bench drives: :class:`~tcms_daq.sim.bench.SimulatedBench`, or a test double
    (``sim.testing.SpringBench``). A physics that can turn the output also has ``move_output(deg, deg/s)``,
    ``output_position_deg`` and ``output_moving``; one that can change its reducer, ``set_specimen(reducer)``."""

    @property
    def now_s(self) -> float: ...

    def advance(self, duration_s: float) -> Samples: ...

    def set_drive_enabled(self, enabled: bool) -> None: ...

    def set_torque_target(self, target_nm: float, slope_nm_per_s: float) -> None: ...


@runtime_checkable
class PositioningPhysics(BenchPhysics, Protocol):
    """A bench physics whose output the loader can turn (profile position mode)."""

    @property
    def output_position_deg(self) -> float: ...

    @property
    def output_moving(self) -> bool: ...

    def move_output(self, target_deg: float, velocity_deg_per_s: float) -> None: ...


class VirtualBench:
    """One simulated bench shared by the virtual drivers: physics, simulated clock, per-channel buffers.

    ``physics`` follows the SimulatedBench contract. Thread-safe: one lock around every physics call.
    real_time_clock: None — the simulated clock (time moves in :meth:`advance` only); else the bench clock's
    ``now`` (s, real time): the physics follows it (:meth:`catch_up`), time stamps are on it.
    """

    def __init__(self, physics: BenchPhysics, name: str = "sim",
                 real_time_clock: Callable[[], float] | None = None, *,
                 transmission: SimTransmission | None = None):
        """``transmission``: the config's ``[sim.transmission]``; when enabled (and the physics is a simulated bench)
        the bench has its second axis: the turning unit (``UnitDriveTrain``) turns the output, the input drive, the
        input torque channel and the angle pair source read it."""
        self.name = name
        self.physics = physics
        self.real_time_clock = real_time_clock
        self.second_axis = (VirtualSecondAxis(self, transmission) if transmission is not None and transmission.enabled
                            else None)
        # bench clock time at the physics' time 0 (0 on the simulated clock: the physics' time is the clock)
        self._clock_origin_s = real_time_clock() - float(physics.now_s) if real_time_clock is not None else 0.0
        self.faults = VirtualFaults()
        self._lock = threading.RLock()
        self._angle = _ChannelBuffer()
        self._torque = _ChannelBuffer()
        self._drive_enabled = False
        self._target_nm = 0.0
        self._applied_nm = 0.0
        self._scheduled: list[tuple[float, Callable[[], Any]]] = []
        self._advancing = False  # a scheduled action that commands the bench does not catch up inside advance

    def at(self, time_s: float, action: Callable[[], Any]) -> None:
        """Run ``action()`` when the simulated clock reaches ``time_s`` (fault injection at a known instant)."""
        with self._lock:
            self._scheduled.append((float(time_s), action))
            self._scheduled.sort(key=lambda item: item[0])

    # -- the clock ----------------------------------------------------------------------------------
    @property
    def real_time(self) -> bool:
        return self.real_time_clock is not None

    def now_s(self) -> float:
        """The bench clock's time of the physics' present (s)."""
        with self._lock:
            return float(self.physics.now_s) + self._clock_origin_s

    def advance(self, duration_s: float) -> None:
        """Run the physics for ``duration_s`` seconds and buffer what the sensors produced."""
        if duration_s <= 0:
            return
        with self._lock:
            self._advancing = True
            try:
                end_s = self.now_s() + duration_s
                while self._scheduled and self._scheduled[0][0] <= end_s:
                    when, action = self._scheduled.pop(0)
                    self._advance(when - self.now_s())
                    action()
                self._advance(end_s - self.now_s())
            finally:
                self._advancing = False

    def catch_up(self) -> None:
        """On the real-time clock: run the physics up to the clock's present (nothing on the simulated clock)."""
        if self.real_time_clock is not None:
            with self._lock:
                if not self._advancing:
                    self.advance(self.real_time_clock() - self.now_s())

    def let_pass(self, duration_s: float) -> None:
        """Let ``duration_s`` of bench time pass: advance the simulation, or wait for the real-time clock."""
        if self.real_time_clock is None:
            self.advance(duration_s)
            return
        until_s = self.real_time_clock() + duration_s
        while self.real_time_clock() < until_s:
            time.sleep(0.001)
        self.catch_up()

    def _advance(self, duration_s: float) -> None:
        if duration_s <= 1e-12:
            return
        axis = self.second_axis
        if axis is None:
            self._advance_physics(duration_s)
            return
        # the second axis: the input drive's profile velocity ramps in steps of INPUT_RAMP_STEP_S, each step's
        # velocity handed to the unit before the physics runs it (as the protocol simulator's drive does per tick)
        remaining = duration_s
        while remaining > 1e-12:
            step = min(remaining, INPUT_RAMP_STEP_S) if axis.drive.ramping else remaining
            axis.drive.ramp(step)
            axis.drivetrain.command(float(self.physics.now_s), axis.drive.velocity_deg_per_s, self._applied_nm)
            self._advance_physics(step)
            remaining -= step

    def _advance_physics(self, duration_s: float) -> None:
        samples = self.physics.advance(duration_s)
        if len(samples) == 0:
            return
        stamps_s = samples.time_s + self._clock_origin_s
        self._angle.append(stamps_s, samples.angle_arcsec, samples.extra)
        self._torque.append(stamps_s, samples.torque_nm)
        applied = samples.extra.get("applied_torque_nm")
        self._applied_nm = float(applied[-1]) if applied is not None else float(samples.torque_nm[-1])
        if self.second_axis is not None:
            self.second_axis.read(samples, stamps_s, applied)

    # -- used by the drivers ------------------------------------------------------------------------
    def take_angle(self) -> Batch:
        with self._lock:
            return self._angle.take()

    def take_torque(self) -> Batch:
        with self._lock:
            return self._torque.take()

    def set_specimen(self, reducer: Any) -> None:
        """The reducer the physics simulates from now on (when the physics can change it); with the second axis its
        turning unit too."""
        with self._lock:
            setter = getattr(self.physics, "set_specimen", None)
            if setter is not None:
                before = getattr(self.physics, "reducer", None)
                setter(reducer)
                if self.second_axis is not None and getattr(before, "name", None) != getattr(reducer, "name", None):
                    self.second_axis.mount(reducer)

    def set_drive_enabled(self, enabled: bool) -> None:
        with self._lock:
            self.catch_up()  # the command acts from the clock's present on
            self._drive_enabled = bool(enabled)
            if not enabled:
                self._target_nm = 0.0
            self.physics.set_drive_enabled(bool(enabled))

    def set_torque_target(self, target_nm: float, slope_nm_per_s: float) -> None:
        with self._lock:
            self.catch_up()
            self._target_nm = float(target_nm)
            self.physics.set_torque_target(float(target_nm), float(slope_nm_per_s))

    def move_output(self, position_deg: float, velocity_deg_per_s: float) -> None:
        """Turn the output (the drive's profile position mode) with the torque demand at zero."""
        with self._lock:
            if not isinstance(self.physics, PositioningPhysics):
                raise CommandRejected(self.name, "this bench's physics cannot turn the output")
            self.physics.set_torque_target(0.0, 1e9)
            self.physics.move_output(float(position_deg), float(velocity_deg_per_s))

    def output_position(self) -> tuple[float | None, bool]:
        """(the output's position in deg or None when the physics has none, moving)."""
        with self._lock:
            if not isinstance(self.physics, PositioningPhysics):
                return None, False
            return float(self.physics.output_position_deg), bool(self.physics.output_moving)

    @property
    def drive_enabled(self) -> bool:
        return self._drive_enabled

    @property
    def applied_torque_nm(self) -> float:
        with self._lock:
            self.catch_up()
            return self._applied_nm

    def inject_drive_fault(self, code: int = GENERIC_DRIVE_FAULT) -> None:
        """Drive fault reaction: torque off at once, FAULT with ``code`` until a fault reset."""
        with self._lock:
            self.faults.drive_fault_code = int(code) or GENERIC_DRIVE_FAULT
            self.set_drive_enabled(False)

    def lose_loader_link(self) -> None:
        """The link to the drive is gone (heartbeat loss): the host sees Disconnected, and the drive's own
        communication watchdog reacts as a CiA 402 drive does: torque off, FAULT 0x8130 (heartbeat error)."""
        with self._lock:
            self.faults.loader_lost = True
            self.inject_drive_fault(0x8130)


class VirtualSecondAxis:
    """The second axis of one :class:`VirtualBench` (``[sim.transmission] enabled``): the turning unit
    (``UnitDriveTrain``) that turns the simulated bench's output, the input drive's state (:class:`InputDriveModel`),
    and the buffers of the angle pair source and the input torque channel, filled at the bench's samples."""

    def __init__(self, bench: VirtualBench, transmission: SimTransmission):
        self.bench = bench
        self.transmission = transmission
        self.drive = InputDriveModel()
        self.pair = _ChannelBuffer()
        self.input_torque = _ChannelBuffer()
        self._rng = np.random.default_rng(int(getattr(bench.physics, "seed", 0)) + 28)
        self.drivetrain: UnitDriveTrain = self._unit(getattr(bench.physics, "reducer", None), None)

    def _unit(self, reducer: Any, previous: UnitDriveTrain | None) -> UnitDriveTrain:
        physics = self.bench.physics
        if not isinstance(physics, SimulatedBench):
            raise ConfigError(f"virtual://{self.bench.name}: [sim.transmission] needs the simulated bench's physics "
                              f"(not a {type(physics).__name__})")
        now = float(physics.now_s)
        start_deg = float(previous.state_at(now)["input_angle_deg"][0]) if previous is not None else 0.0
        unit = UnitDriveTrain.for_bench(physics.config, reducer=reducer, start_s=now, start_deg=start_deg)
        assert unit is not None
        physics.output_rotation = lambda time_s: unit.state_at(time_s)["output_rotation_arcsec"]
        return unit

    def mount(self, reducer: Any) -> None:
        """The turning unit of ``reducer`` from now on, its input at rest where the previous unit's was."""
        self.drivetrain = self._unit(reducer, self.drivetrain)

    def read(self, samples: Samples, stamps_s: np.ndarray, applied: np.ndarray | None) -> None:
        """The input encoder (its counts, latched ``sync_skew_s`` after the output, with its once-per-turn error)
        beside the output encoder's reading, and the input torque channel (with its noise), at the samples' times."""
        tr = self.transmission
        load = applied if applied is not None else samples.torque_nm
        state = self.drivetrain.state_at(samples.time_s, load)
        angle_deg = (state["input_angle_deg"] if tr.sync_skew_s == 0.0
                     else self.drivetrain.state_at(samples.time_s - tr.sync_skew_s)["input_angle_deg"])
        arcsec = angle_deg * 3600.0 + tr.input_encoder_error_arcsec * np.sin(np.radians(angle_deg))
        count = ARCSEC_PER_REV / tr.input_encoder_counts_per_rev
        self.pair.append(stamps_s, samples.angle_arcsec, {INPUT_ANGLE_COLUMN: np.round(arcsec / count) * count})
        noise = tr.input_torque_noise_nm * self._rng.standard_normal(len(stamps_s))
        self.input_torque.append(stamps_s, state["input_torque_nm"] + noise)

    def take_pair(self) -> Batch:
        with self.bench._lock:
            return self.pair.take()

    def take_input_torque(self) -> Batch:
        with self.bench._lock:
            return self.input_torque.take()

    def inject_fault(self, code: int = GENERIC_DRIVE_FAULT) -> None:
        """The input drive's fault reaction: the shaft braked at once, FAULT with ``code`` until a fault reset."""
        with self.bench._lock:
            self.bench.catch_up()
            self.drive.brake("FAULT", int(code) or GENERIC_DRIVE_FAULT)

    def lose_link(self) -> None:
        """The input drive's link is gone: the host sees Disconnected, the drive's watchdog faults it 0x8130."""
        with self.bench._lock:
            self.bench.faults.input_drive_lost = True
            self.inject_fault(0x8130)


PhysicsFactory = Callable[[BenchConfig], object]


@dataclass
class VirtualContext:
    """What the virtual drivers of one composition share: the bench config, the shared benches (by name) and
    how to build the physics of one (``physics_factory(bench_config)``, default the simulated bench)."""

    config: BenchConfig = field(default_factory=BenchConfig)
    physics_factory: PhysicsFactory | None = None
    config_dir: Path | None = None
    real_time_clock: Callable[[], float] = time.monotonic  # the bench's real-time clock (its ``now``)
    benches: dict[str, VirtualBench] = field(default_factory=dict)

    def bench(self, name: str, *, real_time: bool = False) -> VirtualBench:
        if name not in self.benches:
            physics = (self.physics_factory(self.config) if self.physics_factory is not None
                       else SimulatedBench.from_config(self.config, config_dir=self.config_dir))
            if not isinstance(physics, BenchPhysics):
                raise ConfigError(f"virtual://{name}: the physics factory made a {type(physics).__name__}, not a "
                                  "bench physics (now_s, advance, set_drive_enabled, set_torque_target)")
            self.benches[name] = VirtualBench(physics, name=name,
                                              real_time_clock=self.real_time_clock if real_time else None,
                                              transmission=self.config.sim.transmission)
        bench = self.benches[name]
        if bench.real_time != real_time:
            raise ConfigError(f"the instruments of virtual://{name} must all run on one clock "
                              "(all with ?clock=real-time, or none)")
        return bench


def parse_virtual_url(url: str) -> str:
    """``virtual://name`` (optionally ``?clock=simulated|real-time``) → ``name``; ConfigError for anything else."""
    parsed = urlparse(url)
    name = parsed.netloc or parsed.path.lstrip("/")
    if parsed.scheme != "virtual" or not name:
        raise ConfigError(f"virtual driver needs a url like 'virtual://sim', got {url!r}")
    virtual_url_on_real_time(url)  # a bad query is refused here too
    return name


def virtual_url_on_real_time(url: str) -> bool:
    """Whether ``virtual://name?clock=real-time`` asks for the real-time clock (default: the simulated clock)."""
    query = parse_qs(urlparse(url).query, keep_blank_values=True)
    unknown = sorted(set(query) - {"clock"})
    clocks = query.get("clock", ["simulated"])
    if unknown or len(clocks) != 1 or clocks[0] not in ("simulated", "real-time"):
        raise ConfigError(f"virtual driver url {url!r}: the only option is ?clock=simulated or ?clock=real-time")
    return clocks[0] == "real-time"


class VirtualAngleSource:
    """Angle source (arcsec) reading the simulated encoder."""

    def __init__(self, bench: VirtualBench, name: str = "virtual angle"):
        self.name = name
        self.bench = bench
        self.time_source = None if bench.real_time else bench  # on real time: an instrument like any other
        self.connected = False

    def connect(self) -> None:
        self.connected = True
        self.bench.catch_up()
        self.bench.take_angle()  # start fresh: no stale samples from before the connection

    def close(self) -> None:
        self.connected = False

    def read(self) -> Batch:
        if not self.connected:
            raise Disconnected(self.name, "not connected")
        self.bench.catch_up()
        if self.bench.faults.encoder_fault:
            self.bench.take_angle()
            raise DeviceFault(self.name, "encoder fault (display shows '?')")
        batch = self.bench.take_angle()
        return Batch.empty() if self.bench.faults.angle_muted else batch  # an ExtraBatch with the sim's truth


class VirtualTorqueSource:
    """Torque source (N·m) reading the simulated torque sensor, with a tare offset like an amplifier's TAR."""

    def __init__(self, bench: VirtualBench, name: str = "virtual torque"):
        self.name = name
        self.bench = bench
        self.time_source = None if bench.real_time else bench
        self.connected = False
        self.tare_nm = 0.0
        self._last_raw_nm: float | None = None

    def connect(self) -> None:
        self.connected = True
        self.bench.catch_up()
        self.bench.take_torque()

    def close(self) -> None:
        self.connected = False

    def read(self) -> Batch:
        if not self.connected:
            raise Disconnected(self.name, "not connected")
        self.bench.catch_up()
        batch = self.bench.take_torque()
        if len(batch):
            self._last_raw_nm = float(np.mean(batch.value[-20:]))
        if self.bench.faults.torque_muted:
            return Batch.empty()
        return Batch(batch.time_s, batch.value - self.tare_nm + self.bench.faults.torque_offset_nm)

    def tare(self) -> None:
        """Zero the channel at the present load (mean of the latest readings; advances nothing)."""
        if self._last_raw_nm is None:
            self.bench.let_pass(0.01)
            batch = self.bench.take_torque()
            if not len(batch):
                raise DeviceFault(self.name, "no reading to tare on")
            self._last_raw_nm = float(np.mean(batch.value))
        self.tare_nm = self._last_raw_nm


class _VirtualDrive:
    """What the simulated loader and input drive share: the link (connect, close) and its check before a command
    (``lost``: the simulated fault that silences the drive's heartbeat; ``lost_reason``: its words)."""

    name: str
    connected: bool
    lost_reason = "no heartbeat from the drive"

    def lost(self) -> bool:
        raise NotImplementedError

    def _check(self) -> None:
        if self.lost():
            raise Disconnected(self.name, self.lost_reason)
        if not self.connected:
            raise Disconnected(self.name, "not connected")

    def connect(self) -> None:
        self.connected = True

    def close(self) -> None:
        self.connected = False


class VirtualLoader(_VirtualDrive):
    """CiA 402-like loader over the simulated drive: enable/disable, profile torque with a slope, FAULT."""

    def __init__(self, bench: VirtualBench, rated_torque_nm: float, max_torque_nm: float | None = None,
                 name: str = "virtual loader", move_torque_window_nm: float | None = None):
        if rated_torque_nm <= 0:
            raise ConfigError(f"{name}: rated_torque_nm must be > 0, got {rated_torque_nm}")
        self.name = name
        self.bench = bench
        self.time_source = None if bench.real_time else bench
        self.rated_torque_nm = float(rated_torque_nm)
        self.max_torque_nm = float(max_torque_nm if max_torque_nm is not None else rated_torque_nm)
        self.connected = False
        # a move is refused while more torque than this is applied (default 1 % of the rated torque)
        self.move_torque_window_nm = (float(move_torque_window_nm) if move_torque_window_nm is not None
                                      else 0.01 * self.rated_torque_nm)
        self.commands: list[tuple[str, float, float]] = []  # (command, value, sim time) for tests

    def lost(self) -> bool:
        return self.bench.faults.loader_lost

    def enable(self) -> None:
        self._check()
        if self.bench.faults.drive_fault_code:
            raise DeviceFault(self.name, f"drive in FAULT (error 0x{self.bench.faults.drive_fault_code:04X})",
                              self.bench.faults.drive_fault_code)
        self.bench.set_torque_target(0.0, self.max_torque_nm)
        self.bench.set_drive_enabled(True)
        self.commands.append(("enable", 1.0, self.bench.now_s()))

    def disable(self) -> None:
        self._check()
        self.bench.set_torque_target(0.0, self.max_torque_nm * 10)
        self.bench.set_drive_enabled(False)
        self.commands.append(("disable", 0.0, self.bench.now_s()))

    def _check_operation_enabled(self) -> None:
        """The drive answers, is not in FAULT and is in OPERATION ENABLED; else the error a drive would give."""
        self._check()
        code = self.bench.faults.drive_fault_code
        if code:
            raise DeviceFault(self.name, f"drive in FAULT (error 0x{code:04X})", code)
        if not self.bench.drive_enabled:
            raise CommandRejected(self.name, "drive not in OPERATION ENABLED")

    def set_torque(self, target_nm: float, slope_nm_per_s: float | None = None) -> None:
        if not np.isfinite(target_nm) or abs(target_nm) > self.max_torque_nm:
            raise CommandRejected(self.name, f"target torque {target_nm} N·m outside ±{self.max_torque_nm} N·m")
        if slope_nm_per_s is not None and not (np.isfinite(slope_nm_per_s) and slope_nm_per_s > 0):
            raise CommandRejected(self.name, f"torque slope must be > 0 N·m/s, got {slope_nm_per_s}")
        self._check_operation_enabled()
        slope = float(slope_nm_per_s) if slope_nm_per_s is not None else self.max_torque_nm
        self.bench.set_torque_target(float(target_nm), slope)
        self.commands.append(("torque", float(target_nm), self.bench.now_s()))

    def move_to(self, position_deg: float, velocity_deg_per_s: float) -> None:
        """Profile position: turn the output to ``position_deg`` (deg) at ``velocity_deg_per_s``; refused while
        torque is applied, while disabled or in FAULT."""
        if not (np.isfinite(position_deg) and np.isfinite(velocity_deg_per_s) and velocity_deg_per_s > 0):
            raise CommandRejected(self.name, f"move to {position_deg} deg at {velocity_deg_per_s} deg/s: need a "
                                  "finite position and a velocity > 0")
        self._check_operation_enabled()
        torque = self.bench.applied_torque_nm
        if abs(torque) > self.move_torque_window_nm:
            raise CommandRejected(self.name, f"{torque:.3g} N·m on the output: no move under torque "
                                  f"(window ±{self.move_torque_window_nm:g} N·m)")
        self.bench.move_output(float(position_deg), float(velocity_deg_per_s))
        self.commands.append(("move", float(position_deg), self.bench.now_s()))

    def status(self) -> LoaderStatus:
        self._check()
        code = self.bench.faults.drive_fault_code
        if code:
            state = "FAULT"
        else:
            state = "OPERATION ENABLED" if self.bench.drive_enabled else "SWITCH ON DISABLED"
        torque = self.bench.applied_torque_nm if not code else 0.0
        position_deg, moving = self.bench.output_position()
        return LoaderStatus(state=state, torque_actual_nm=torque, fault=bool(code), error_code=code,
                            time_s=self.bench.now_s(), position_deg=position_deg, moving=moving)

    def set_specimen(self, reducer: Any) -> None:
        """The simulated loader's bench mounts the requested reducer (``Bench.set_specimen``)."""
        self.bench.set_specimen(reducer)

    def fault_reset(self) -> None:
        self._check()
        self.bench.faults.drive_fault_code = 0
        self.commands.append(("fault_reset", 0.0, self.bench.now_s()))


class VirtualAnglePair:
    """The angle pair source of the second axis (``[instruments.input_angle]``): the output encoder's reading in
    ``value`` (the same encoder the angle source reads) and the input encoder's (input arcsec) in
    ``extra["input_angle_arcsec"]``, latched together at the bench's samples (as the two-axis counter's pairs)."""

    def __init__(self, bench: VirtualBench, name: str = "virtual angle pair"):
        assert bench.second_axis is not None
        self.name = name
        self.bench = bench
        self.axis = bench.second_axis
        self.time_source = None if bench.real_time else bench
        self.connected = False

    def connect(self) -> None:
        self.connected = True
        self.bench.catch_up()
        self.axis.take_pair()

    def close(self) -> None:
        self.connected = False

    def read(self) -> Batch:
        if not self.connected:
            raise Disconnected(self.name, "not connected")
        self.bench.catch_up()
        batch = self.axis.take_pair()
        if self.bench.faults.encoder_fault:
            raise DeviceFault(self.name, "encoder signal fault on axis 1 (output)")
        return Batch.empty() if self.bench.faults.input_angle_muted else batch


class VirtualInputTorque(VirtualTorqueSource):
    """The input torque channel of the second axis (``[instruments.input_torque]``), tared like the AED."""

    def __init__(self, bench: VirtualBench, name: str = "virtual input torque"):
        super().__init__(bench, name)
        assert bench.second_axis is not None
        self._take = bench.second_axis.take_input_torque

    def connect(self) -> None:
        self.connected = True
        self.bench.catch_up()
        self._take()

    def read(self) -> Batch:
        if not self.connected:
            raise Disconnected(self.name, "not connected")
        self.bench.catch_up()
        batch = self._take()
        if len(batch):
            self._last_raw_nm = float(np.mean(batch.value[-20:]))
        if self.bench.faults.input_torque_muted:
            return Batch.empty()
        return Batch(batch.time_s, batch.value - self.tare_nm)

    def tare(self) -> None:
        if self._last_raw_nm is None:
            self.bench.let_pass(0.01)
            batch = self._take()
            if not len(batch):
                raise DeviceFault(self.name, "no reading to tare on")
            self._last_raw_nm = float(np.mean(batch.value))
        self.tare_nm = self._last_raw_nm


class VirtualInputDrive(_VirtualDrive):
    """The input drive of the second axis (``[instruments.input_drive]``): ``drivers.base.InputDrive`` over the
    in-process bench's :class:`InputDriveModel` (profile velocity at the input shaft, deg/s)."""

    def __init__(self, bench: VirtualBench, *, max_velocity_deg_per_s: float, acceleration_deg_per_s2: float,
                 name: str = "virtual input drive"):
        self.name = name
        self.bench = bench
        self.time_source = None if bench.real_time else bench
        self.max_velocity_deg_per_s = float(max_velocity_deg_per_s)
        self.acceleration_deg_per_s2 = float(acceleration_deg_per_s2)
        self.connected = False
        self.commands: list[tuple[str, float, float]] = []  # (command, value, sim time) for tests
        assert bench.second_axis is not None
        self.axis = bench.second_axis

    @property
    def model(self) -> InputDriveModel:
        return self.axis.drive

    lost_reason = "no heartbeat from the input drive"

    def lost(self) -> bool:
        return self.bench.faults.input_drive_lost

    def enable(self) -> None:
        self._check()
        with self.bench._lock:
            self.bench.catch_up()
            model = self.model
            if model.state == "FAULT":
                raise DeviceFault(self.name, f"drive in FAULT (error 0x{model.error_code:04X})", model.error_code)
            model.acceleration_deg_per_s2 = self.acceleration_deg_per_s2
            model.state, model.target_deg_per_s, model.disable_pending = "OPERATION ENABLED", 0.0, False
        self.commands.append(("enable", 1.0, self.bench.now_s()))

    def set_velocity(self, velocity_deg_per_s: float) -> None:
        if not isinstance(velocity_deg_per_s, int | float) or not math.isfinite(velocity_deg_per_s):
            raise CommandRejected(self.name, f"velocity must be a finite number of deg/s, got {velocity_deg_per_s!r}")
        if abs(velocity_deg_per_s) > self.max_velocity_deg_per_s + 1e-9:
            raise CommandRejected(self.name, f"velocity {velocity_deg_per_s:g} deg/s exceeds the limit "
                                  f"±{self.max_velocity_deg_per_s:g} deg/s")
        self._check()
        with self.bench._lock:
            self.bench.catch_up()
            model = self.model
            if model.state == "FAULT":
                raise DeviceFault(self.name, f"drive in FAULT (error 0x{model.error_code:04X})", model.error_code)
            if model.state != "OPERATION ENABLED":
                raise CommandRejected(self.name, "drive not in OPERATION ENABLED")
            model.target_deg_per_s = float(velocity_deg_per_s)
        self.commands.append(("velocity", float(velocity_deg_per_s), self.bench.now_s()))

    def disable(self) -> None:
        """Target 0 at the profile deceleration; the drive leaves OPERATION ENABLED once at rest."""
        self._check()
        with self.bench._lock:
            self.bench.catch_up()
            model = self.model
            if model.state == "OPERATION ENABLED":
                model.target_deg_per_s = 0.0
                if model.velocity_deg_per_s == 0.0:
                    model.state = "SWITCH ON DISABLED"
                else:
                    model.disable_pending = True
        self.commands.append(("disable", 0.0, self.bench.now_s()))

    def status(self) -> InputDriveStatus:
        self._check()
        with self.bench._lock:
            self.bench.catch_up()
            model = self.model
            now = float(self.bench.physics.now_s)
            position = float(self.axis.drivetrain.state_at(now)["input_angle_deg"][0])
            return InputDriveStatus(state=model.state, velocity_deg_per_s=model.velocity_deg_per_s,
                                    fault=model.state == "FAULT", error_code=model.error_code,
                                    position_deg=position, time_s=self.bench.now_s())

    def fault_reset(self) -> None:
        self._check()
        with self.bench._lock:
            if self.model.state == "FAULT":
                self.model.brake("SWITCH ON DISABLED")
        self.commands.append(("fault_reset", 0.0, self.bench.now_s()))

    def set_torque(self, target_nm: float, slope_nm_per_s: float | None = None) -> None:
        raise CommandRejected(self.name, "an input drive in profile velocity takes velocities (set_velocity), "
                              "not torques")


class VirtualOptions(DriverOptions):
    """[instruments.<kind>] of ``driver = "virtual"``: the in-process simulated bench ``url`` names
    (``virtual://NAME``, ``?clock=real-time`` to follow the real-time clock); a loader's rated torque (N·m, 0x6076
    of a real drive; default its ``max_torque_nm``, else 2000) and limit (N·m; default the bench's limit)."""

    url: str = Field("virtual://sim", min_length=1, description="the simulated bench: virtual://NAME")
    rated_torque_nm: float | None = Field(None, gt=0.0, description="the loader's rated torque (N·m)")
    max_torque_nm: float | None = Field(None, gt=0.0, description="the loader's limit (N·m)")
    max_velocity_deg_per_s: float = Field(15000.0, gt=0.0, description="input drive: never command more "
                                          "(deg/s at the input)")
    acceleration_deg_per_s2: float = Field(60000.0, gt=0.0, description="input drive: profile acceleration and "
                                           "deceleration (deg/s²)")


VirtualInstrument = (VirtualAngleSource | VirtualTorqueSource | VirtualLoader | VirtualAnglePair | VirtualInputDrive)


class VirtualDriver:
    """Registry entry ``virtual``: builds the angle/torque/loader driver of kind ``kind`` on the shared bench.

    The bench composer calls :meth:`from_config` with a context holding the shared benches so the three
    instruments of ``virtual://sim`` drive one physics object and one clock.
    """

    options_model = VirtualOptions

    @staticmethod
    def build(*, kind: str, url: str = "virtual://sim", context: VirtualContext | None = None,
              rated_torque_nm: float | None = None, max_torque_nm: float | None = None,
              max_velocity_deg_per_s: float = 15000.0, acceleration_deg_per_s2: float = 60000.0
              ) -> VirtualInstrument:
        """The instrument ``kind`` of the bench ``url`` names; a loader's rated torque (N·m, 0x6076 of a real
        drive; default its ``max_torque_nm``, else 2000) and limit (N·m; default its rated torque); the second
        axis's (input_drive, input_torque, input_angle) when the bench config has ``[sim.transmission] enabled``."""
        ctx = context or VirtualContext()
        bench = ctx.bench(parse_virtual_url(url), real_time=virtual_url_on_real_time(url))
        if kind == "angle":
            return VirtualAngleSource(bench)
        if kind == "torque":
            return VirtualTorqueSource(bench)
        if kind == "loader":
            rated = rated_torque_nm if rated_torque_nm is not None else max_torque_nm
            return VirtualLoader(bench, float(rated if rated is not None else 2000.0), max_torque_nm)
        if kind in ("input_drive", "input_torque", "input_angle"):
            if bench.second_axis is None:
                raise ConfigError(f"[instruments.{kind}]: the in-process bench virtual://{bench.name} turns its input "
                                  "only with [sim.transmission] enabled = true")
            if kind == "input_drive":
                return VirtualInputDrive(bench, max_velocity_deg_per_s=max_velocity_deg_per_s,
                                         acceleration_deg_per_s2=acceleration_deg_per_s2)
            return VirtualInputTorque(bench) if kind == "input_torque" else VirtualAnglePair(bench)
        raise ConfigError(f"virtual driver: unknown instrument kind {kind!r} (angle, torque, loader, input_drive, "
                          "input_torque, input_angle)")

    @classmethod
    def from_config(cls, kind: str, options: VirtualOptions, context: CompositionContext) -> VirtualInstrument:
        """Called by the bench composer with the validated options and the context its instruments share; a
        loader without ``max_torque_nm`` takes the bench's limit."""
        ctx = context.shared.get("virtual")
        if not isinstance(ctx, VirtualContext):
            ctx = VirtualContext(context.config, context.physics_factory, context.config_dir,
                                 context.real_time_clock or time.monotonic)
            context.shared["virtual"] = ctx
        max_torque_nm = options.max_torque_nm
        if kind == "loader" and max_torque_nm is None:
            bench_max_nm = context.bench_max_torque_nm
            max_torque_nm = bench_max_nm if math.isfinite(bench_max_nm) else 2000.0
        return cls.build(kind=kind, context=ctx, url=options.url, rated_torque_nm=options.rated_torque_nm,
                         max_torque_nm=max_torque_nm, max_velocity_deg_per_s=options.max_velocity_deg_per_s,
                         acceleration_deg_per_s2=options.acceleration_deg_per_s2)

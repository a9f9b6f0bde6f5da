"""The simulated bench: reducer physics, servo loader and sensors on one simulated clock.

``SimulatedBench`` is the in-process ground truth every simulated instrument reads (the virtual drivers, the
ND 287 / AED / CiA 402 protocol simulators). Time advances only when ``advance()`` is called, so a test runs
as fast as the arrays can be computed. Per batch, vectorised:

    demand (profile-torque ramp) → torque loop lag → applied torque → reducer twist (sim.physics)
    → optional effects (hook, off by default) → measuring chain (hook, default identity)
    → torque sensor (gain, offset, noise) and encoder (interpolation error, noise, quantisation)

Hooks:
* ``measuring_chain(true_angle_arcsec, torque_nm, time_s) -> encoder_arcsec``: geometric errors of the chain
  between reducer output and encoder scale (filled by the compensation module from a geometry file).
* ``effects(cols) -> cols | None``: hidden effects (sim/effects.py). ``cols`` holds ``time_s``,
  ``applied_torque_nm``, ``true_angle_arcsec`` and the two sensor inputs ``torque_signal_nm`` and
  ``angle_signal_arcsec``, which an effect may change (in place or in a returned dict) before the measuring chain and the sensors.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
from tcms_daq.sim.drive import TorqueDrive
from tcms_daq.sim.effects import from_config as effects_from_config
from tcms_daq.sim.physics import (
    LoopTruth,
    ReducerPhysics,
    TwistState,
    loop_truth,
    physics_from_spec,
    twist_arcsec,
)
from tcms_daq.sim.reducer_model import RichReducerModel, RichState
from tcms_daq.sim.sensors import EncoderModel, TorqueSensorModel

from tcms_daq.config.loader import get_reducer, load_reducers_for
from tcms_daq.config.models import BenchConfig, ReducerSpec, SimConfig
from tcms_daq.errors import ConfigError
from tcms_daq.samples import Samples
from tcms_daq.units import ARCSEC_PER_DEG

MeasuringChain = Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]
Effects = Callable[[dict[str, np.ndarray]], "dict[str, np.ndarray] | None"]


class SimulatedBench:
    """Physics of the bench on a simulated clock (s). Thread-safe: commands and ``advance`` take a lock."""

    def __init__(
        self,
        physics: ReducerPhysics | SimConfig | BenchConfig | None = None,
        *,
        reducer: ReducerSpec | None = None,
        catalogue: Mapping[str, ReducerSpec] | None = None,
        sample_rate_hz: float | None = None,
        torque_loop_time_constant_s: float | None = None,
        max_torque_nm: float | None = None,
        torque_noise_nm: float | None = None,
        torque_gain: float | None = None,
        torque_offset_nm: float | None = None,
        encoder_noise_arcsec: float | None = None,
        encoder_resolution_arcsec: float | None = None,
        encoder_signal_period_arcsec: float | None = None,
        encoder_interpolation_error_arcsec: float | None = None,
        seed: int | None = None,
        measuring_chain: MeasuringChain | None = None,
        effects: Effects | None = None,
    ):
        """``physics``: forward-model parameters, or a validated config (the [sim] table, or a whole bench config),
        or None (defaults: the [sim] defaults and the catalogue's ``sim.reducer``).

        Keyword arguments left at None come from the config ([sim] and [bench] max_torque_nm); with a
        ReducerPhysics and no config they come from the SimConfig defaults (config/bench-sim.toml has the same).
        Without an explicit ``measuring_chain`` the config's ``[sim] geometry`` file (if any) gives it.
        The reducer is ``reducer``, else ``sim.reducer`` looked up in ``catalogue`` (default: the config's catalogue).
        """
        cfg = _as_bench_config(None if isinstance(physics, ReducerPhysics) else physics)
        sim = cfg.sim
        if isinstance(physics, ReducerPhysics):
            params = physics
        else:
            if reducer is None:
                cat = catalogue if catalogue is not None else load_reducers_for(cfg)
                reducer = get_reducer(dict(cat), sim.reducer, cfg.source_path)
            params = physics_from_spec(reducer)

        def pick(value, default):
            return default if value is None else value

        self.physics = params
        self.reducer = reducer
        self.config = cfg
        # [sim] model = "rich": position-, rate- and time-dependent reducer (sim/reducer_model.py)
        self.rich_model = RichReducerModel(params, sim.rich) if sim.model == "rich" else None
        self._rich_state = RichState()
        # the output's position (deg), turned by the loader's position mode: (from, to, start s, deg/s) while moving
        self._position_deg = 0.0
        self._move: tuple[float, float, float, float] | None = None
        self.sample_rate_hz = float(pick(sample_rate_hz, sim.sample_rate_hz))
        self.seed = int(pick(seed, sim.seed))
        self.max_torque_nm = float(pick(max_torque_nm, cfg.bench.max_torque_nm))
        self.torque_loop_time_constant_s = float(pick(torque_loop_time_constant_s, sim.torque_loop_time_constant_s))
        self.drive = TorqueDrive(self.sample_rate_hz, self.torque_loop_time_constant_s, self.max_torque_nm)
        torque_rng, angle_rng = (np.random.default_rng(s) for s in np.random.SeedSequence(self.seed).spawn(2))
        self.torque_sensor = TorqueSensorModel(
            torque_rng, pick(torque_noise_nm, sim.torque_noise_nm), pick(torque_gain, sim.torque_gain),
            pick(torque_offset_nm, sim.torque_offset_nm))
        self.encoder = EncoderModel(
            angle_rng, pick(encoder_noise_arcsec, sim.encoder_noise_arcsec),
            pick(encoder_resolution_arcsec, sim.encoder_resolution_arcsec),
            pick(encoder_signal_period_arcsec, sim.encoder_signal_period_arcsec),
            pick(encoder_interpolation_error_arcsec, sim.encoder_interpolation_error_arcsec))
        if measuring_chain is None and sim.geometry:
            measuring_chain = _measuring_chain_from_geometry(cfg.resolve(sim.geometry))
        self.measuring_chain = measuring_chain
        if effects is None and sim.effects:
            effects = _effects_from_config(sim.effects, seed=self.seed, source=cfg.source_path)
        self.effects = effects
        # the output's rotation driven from the input (arcsec at the sample times; the turning unit's, set by the
        # in-process second axis: sim.virtual), added to the true angle before the measuring chain; None: none
        self.output_rotation: Callable[[np.ndarray], np.ndarray] | None = None
        self._twist_state = TwistState()
        self._n = 0  # samples emitted; sample k is at k / sample_rate_hz
        self._now_s = 0.0
        self._last: dict[str, float] = {
            "time_s": 0.0, "applied_torque_nm": 0.0, "true_angle_arcsec": 0.0, "torque_nm": 0.0,
            "angle_arcsec": 0.0, "demand_nm": 0.0,
        }
        self._lock = threading.RLock()

    # ------------------------------------------------------------------------------------------ construction

    @classmethod
    def from_config(
        cls,
        cfg: BenchConfig,
        reducer: ReducerSpec | None = None,
        *,
        seed: int | None = None,
        measuring_chain: MeasuringChain | None = None,
        effects: Effects | None = None,
        config_dir: str | Path | None = None,
    ) -> SimulatedBench:
        """The one simulated-bench factory: a bench from a validated bench config ([sim], [bench]) and a catalogue
        reducer (default: ``sim.reducer``). Files the config names (``[sim] geometry``, the catalogue) are relative
        to the config file, or to ``config_dir`` for a config not read from a file."""
        bench_cfg = cfg
        if cfg.source_path is None and config_dir is not None:
            bench_cfg = cfg.model_copy(update={"source_path": str(Path(config_dir) / "<bench config>")})
        return cls(bench_cfg, reducer=reducer, seed=seed, measuring_chain=measuring_chain, effects=effects)

    def set_specimen(self, reducer: ReducerSpec) -> None:
        """Mount another catalogue reducer: its physics from now on, a virgin hysteresis state (between tests,
        at zero torque). The reducer already mounted stays as it is, friction state included."""
        with self._lock:
            if self.reducer is not None and self.reducer.name == reducer.name:
                return
            self.physics = physics_from_spec(reducer)
            self.reducer = reducer
            self._twist_state = TwistState(float(self.drive.applied_nm), 0.0)
            if self.rich_model is not None:
                self.rich_model = RichReducerModel(self.physics, self.rich_model.config)
                self._rich_state = RichState(TwistState(float(self.drive.applied_nm), 0.0), 0.0, self._now_s)

    # ------------------------------------------------------------------------------------------ commands

    @property
    def now_s(self) -> float:
        """Simulated time (s) since the bench was created."""
        return self._now_s

    @property
    def drive_enabled(self) -> bool:
        return self.drive.enabled

    def set_drive_enabled(self, enabled: bool) -> None:
        """Enable the loader (torque demand ramps from 0 to the target) or disable it (demand 0 at once; a move
        of the output stops where it is)."""
        with self._lock:
            self.drive.set_enabled(bool(enabled), self._now_s)
            if not enabled:
                self.stop_output()

    # -- the output's position (the loader's profile position mode) ------------------------------------------

    @property
    def output_position_deg(self) -> float:
        """Where the loader has turned the output (deg, the position part of the true angle)."""
        with self._lock:
            return float(self._position_at(np.array([self._now_s]))[0])

    @property
    def output_moving(self) -> bool:
        with self._lock:
            return self._move is not None and self._position_deg != self._move[1]

    def move_output(self, target_deg: float, velocity_deg_per_s: float) -> None:
        """Turn the output to ``target_deg`` at ``velocity_deg_per_s`` (the drive applies no torque meanwhile)."""
        if not (math.isfinite(target_deg) and math.isfinite(velocity_deg_per_s) and velocity_deg_per_s > 0):
            raise ValueError(f"move to {target_deg} deg at {velocity_deg_per_s} deg/s: need finite values, "
                             "velocity > 0")
        with self._lock:
            start = self.output_position_deg
            self._position_deg = start
            self._move = (start, float(target_deg), self._now_s, float(velocity_deg_per_s))

    def stop_output(self) -> None:
        """Halt a move where the output is now."""
        with self._lock:
            if self._move is not None:
                self._position_deg = self.output_position_deg
                self._move = None

    def _position_at(self, time_s: np.ndarray) -> np.ndarray:
        """Output position (deg) at the given times of the present move (or where it rests)."""
        if self._move is None:
            return np.full(time_s.shape, self._position_deg)
        start, target, t0, velocity = self._move
        travelled = np.clip((time_s - t0) * velocity, 0.0, abs(target - start))
        return start + math.copysign(1.0, target - start) * travelled

    def set_torque_target(self, target_nm: float, slope_nm_per_s: float | None = None) -> None:
        """Profile torque: ramp the demand to ``target_nm`` at ``slope_nm_per_s`` (None: a step).

        The target is clamped to ±max_torque_nm (what the motor can deliver); interlocks are not the physics' job.
        """
        with self._lock:
            self.drive.command(float(target_nm), slope_nm_per_s, self._now_s)

    def tare(self, duration_s: float = 0.1) -> float:
        """Zero the torque reading: average it over ``duration_s`` (the clock advances) and subtract from now on."""
        with self._lock:
            batch = self.advance(duration_s)
            if len(batch):
                self.torque_sensor.tare_nm += float(np.mean(batch.torque_nm))
            return self.torque_sensor.tare_nm

    # ------------------------------------------------------------------------------------------ clock

    def advance(self, duration_s: float) -> Samples:
        """Run the simulated clock forward by ``duration_s`` and return the samples taken meanwhile.

        Columns: ``time_s``; ``torque_nm`` (torque sensor reading); ``angle_arcsec`` (raw encoder reading); extra
        ``applied_torque_nm`` (true torque in the reducer), ``true_angle_arcsec`` (true output twist) and
        ``demand_nm`` (the drive's torque demand).
        """
        if not duration_s >= 0 or not math.isfinite(duration_s):
            raise ValueError(f"duration_s must be finite and >= 0 (got {duration_s})")
        with self._lock:
            end_s = self._now_s + duration_s
            n_end = int(math.floor(end_s * self.sample_rate_hz + 1e-9))
            k = np.arange(self._n + 1, n_end + 1, dtype=float)
            self._now_s = end_s
            if k.size == 0:
                return _empty_samples()
            self._n = n_end
            time_s = k / self.sample_rate_hz
            demand, applied = self.drive.step(time_s)
            position_deg = self._position_at(time_s)
            if self._move is not None and time_s[-1] >= self._move[2] + abs(self._move[1] - self._move[0]) / self._move[3]:
                self._position_deg, self._move = self._move[1], None  # arrived
            if self.rich_model is not None:
                twist, self._rich_state = self.rich_model.twist_arcsec(applied, time_s, float(position_deg[-1]),
                                                                       self._rich_state)
            else:
                twist, self._twist_state = twist_arcsec(applied, self.physics, self._twist_state)
            # the true angle is the output's absolute angle: its position plus the twist (0 at position 0)
            true_angle = twist + position_deg * ARCSEC_PER_DEG if (self._position_deg or self._move) else twist
            if self.output_rotation is not None:  # the second axis turns the output through the reducer
                true_angle = true_angle + np.asarray(self.output_rotation(time_s), dtype=float)
            cols = {
                "time_s": time_s,
                "applied_torque_nm": applied,
                "true_angle_arcsec": true_angle,
                "torque_signal_nm": applied,
                "angle_signal_arcsec": true_angle,
                "drive_enabled": np.full(len(time_s), self.drive.enabled),
            }
            if self.effects is not None:
                returned = self.effects(cols)
                if returned is not None:
                    cols = returned
            if self.measuring_chain is not None:
                # after the effects: they are the catalogue's forms in the reducer's angle, which is what the
                # compensated reading gives back (added after the chain, the compensation would rescale them)
                cols["angle_signal_arcsec"] = np.asarray(
                    self.measuring_chain(cols["angle_signal_arcsec"], applied, time_s), dtype=float)
            torque_reading = self.torque_sensor.read(cols["torque_signal_nm"])
            angle_reading = self.encoder.read(cols["angle_signal_arcsec"])
            self._last = {
                "time_s": float(time_s[-1]),
                "applied_torque_nm": float(applied[-1]),
                "true_angle_arcsec": float(true_angle[-1]),
                "torque_nm": float(torque_reading[-1]),
                "angle_arcsec": float(angle_reading[-1]),
                "demand_nm": float(demand[-1]),
            }
            return Samples(
                time_s,
                torque_reading,
                angle_reading,
                {"applied_torque_nm": applied, "true_angle_arcsec": true_angle, "demand_nm": demand},
            )

    # ------------------------------------------------------------------------------------------ state

    def snapshot(self) -> dict[str, Any]:
        """The present state: clock, drive and the last sample's values (plain floats/bools, JSON-ready)."""
        with self._lock:
            return {
                "now_s": self._now_s,
                "samples": self._n,
                "sample_rate_hz": self.sample_rate_hz,
                "drive_enabled": self.drive.enabled,
                "target_nm": self.drive.target_nm,
                "slope_nm_per_s": self.drive.slope_nm_per_s,
                "demand_now_nm": self.drive.demand_setpoint_nm(self._now_s),
                "output_position_deg": self.output_position_deg,
                "reducer_model": "rich" if self.rich_model is not None else "simple",
                "reducer": self.physics.name,
                "tare_nm": self.torque_sensor.tare_nm,
                "last": dict(self._last),
            }

    def truth(self, test_torque_nm: float | None = None, lost_motion_pct: float | None = None,
              rigidity_interval: tuple[float, float] = (0.5, 1.0)) -> LoopTruth:
        """Exact characteristics of the simulated reducer's steady loop between ±test torque (sim.physics)."""
        rated = self.reducer.rated_torque_nm if self.reducer is not None else None
        if test_torque_nm is None:
            if rated is None:
                raise ValueError("test_torque_nm is needed when the bench has no catalogue reducer")
            test_torque_nm = rated
        pct = lost_motion_pct if lost_motion_pct is not None else (
            self.reducer.lost_motion_pct if self.reducer is not None else 3.0)
        return loop_truth(self.physics, test_torque_nm, rated if rated is not None else test_torque_nm, pct,
                          rigidity_interval)

    def profile_truth(self, segments: Any, test_torque_nm: float, position_deg: float = 0.0,
                      lost_motion_pct: float | None = None,
                      rigidity_interval: tuple[float, float] = (0.5, 1.0)) -> dict[str, Any]:
        """The truth of a test with these profile segments at output position ``position_deg``: the closed-form
        steady loop of the simple model (``truth``), or the rich model's loops computed numerically
        (``sim.truth``: they depend on the rate, the dwells and the position)."""
        if self.rich_model is None:
            return self.truth(test_torque_nm, lost_motion_pct, rigidity_interval).to_dict()
        from tcms_daq.sim.truth import profile_truth

        rated = self.reducer.rated_torque_nm if self.reducer is not None else test_torque_nm
        pct = lost_motion_pct if lost_motion_pct is not None else (
            self.reducer.lost_motion_pct if self.reducer is not None else 3.0)
        return profile_truth(self.rich_model, segments, position_deg, sample_rate_hz=self.sample_rate_hz,
                             time_constant_s=self.torque_loop_time_constant_s, rated_torque_nm=rated,
                             lost_motion_pct=pct, rigidity_interval=rigidity_interval)


def _empty_samples() -> Samples:
    e = np.empty(0)
    return Samples(e, e, e, {"applied_torque_nm": e, "true_angle_arcsec": e, "demand_nm": e})


def _as_bench_config(cfg: SimConfig | BenchConfig | None) -> BenchConfig:
    if cfg is None:
        return BenchConfig()
    if isinstance(cfg, SimConfig):
        return BenchConfig(sim=cfg)
    return cfg


def _measuring_chain_from_geometry(path: str) -> MeasuringChain:
    """The encoder reading through the measuring chain of a geometry file (the compensation module's forward
    model): what ``[sim] geometry`` names."""
    from tcms_daq.compensation import Compensator

    return Compensator.from_geometry(path).encoder_reading


def _effects_from_config(table: dict[str, Any], *, seed: int, source: str | None) -> Effects | None:
    """The hidden-effects hook of a [sim.effects] table (``sim.effects.from_config``); errors name the file."""
    where = source or "<config>"
    try:
        return effects_from_config(table, seed=seed)
    except ConfigError as exc:
        message = str(exc)
        raise ConfigError(message if message.startswith(where) else f"{where}: {message}") from None

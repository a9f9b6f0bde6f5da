"""Recorded runs of the simulated station (both axes, all channels) for the turning tests: what the tests, the trials
and the benchmarks feed the evaluations (``tcms_daq.transmission``), with the exact truth beside them.

A run is built from a profile (:func:`te_profile`, :func:`no_load_profile`, :func:`efficiency_profile`: the input
drive in velocity mode; :func:`starting_profile`: in torque mode) and the station's sensors (:class:`StationSensors`,
from ``[sim]`` and ``[sim.transmission]``): the unit's physics (``sim.transmission``) on one sample grid, then

* the input drive's speed ripple (a share of the speed at an order per input revolution),
* the output encoder through the measuring chain (``[sim] geometry``: the DH chain's forward model), its own
  graduation and mounting error over the revolution (orders 1 and 2), and the encoder model (interpolation error,
  noise, quantisation: ``sim.sensors.EncoderModel``),
* the input encoder: its counts and its once-per-input-revolution error (the same encoder model with a period of
  one input revolution), latched ``sync_skew_s`` after the output encoder,
* the two torque readings with their gain, zero offset and noise.

Columns (``StationRun.columns``): ``time_s``, ``input_angle_arcsec`` (input arcsec), ``output_angle_arcsec``,
``input_torque_nm``, ``output_torque_nm``, ``temperature_c``, and the true values ``true_input_angle_arcsec``,
``true_output_angle_arcsec``, ``true_input_torque_nm``, ``true_output_torque_nm``, ``input_speed_rpm``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from tcms_daq.sim.sensors import EncoderModel, TorqueSensorModel
from tcms_daq.sim.transmission import UnitPhysics, UnitState, turn, turn_with_torque

from tcms_daq.config.models import SimConfig
from tcms_daq.units import ARCSEC_PER_RAD, ARCSEC_PER_REV

MeasuringChain = Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]


@dataclass(frozen=True)
class SpeedSegment:
    """The input drive holds ``speed_rpm`` for ``duration_s`` (after ramping to it at the profile's acceleration)
    while the loader applies ``load_torque_nm``."""

    speed_rpm: float
    duration_s: float
    load_torque_nm: float = 0.0


@dataclass(frozen=True)
class TorqueRamp:
    """The input drive ramps its torque to ``target_nm`` at ``rate_nm_per_s`` and holds it ``dwell_s``."""

    target_nm: float
    rate_nm_per_s: float
    dwell_s: float = 0.0


@dataclass(frozen=True)
class StationSensors:
    """The station's measuring chain in the simulation (``[sim]`` and ``[sim.transmission]``)."""

    sample_rate_hz: float = 1000.0
    output_encoder_noise_arcsec: float = 0.2
    output_encoder_resolution_arcsec: float = 0.1
    output_encoder_signal_period_arcsec: float = 72.0
    output_encoder_interpolation_error_arcsec: float = 0.0
    input_encoder_counts_per_rev: int = 2**20
    input_encoder_error_arcsec: float = 0.0
    sync_skew_s: float = 0.0
    speed_ripple_pct: float = 0.0
    speed_ripple_per_input_rev: float = 1.0
    input_torque_noise_nm: float = 0.002
    output_torque_noise_nm: float = 0.3
    temperature_c: float = 25.0
    # the output encoder's graduation/mounting error over the revolution: (c1, s1, c2, s2) ″ of cos/sin at orders 1, 2
    output_encoder_graduation_arcsec: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
    input_encoder_error_phase_rad: float = 0.0
    input_torque_gain: float = 1.0
    input_torque_offset_nm: float = 0.0
    output_torque_gain: float = 1.0
    output_torque_offset_nm: float = 0.0

    @classmethod
    def from_config(cls, sim: SimConfig, sample_rate_hz: float | None = None) -> StationSensors:
        tr = sim.transmission
        return cls(sample_rate_hz or sim.sample_rate_hz, sim.encoder_noise_arcsec, sim.encoder_resolution_arcsec,
                   sim.encoder_signal_period_arcsec, sim.encoder_interpolation_error_arcsec,
                   tr.input_encoder_counts_per_rev, tr.input_encoder_error_arcsec, tr.sync_skew_s,
                   tr.speed_ripple_pct, tr.speed_ripple_per_input_rev, tr.input_torque_noise_nm, sim.torque_noise_nm,
                   tr.temperature_c)


@dataclass(frozen=True)
class StationRun:
    """A recorded run: its columns (module docstring) and the unit it was recorded on."""

    columns: dict[str, np.ndarray]
    unit: UnitPhysics
    sensors: StationSensors


# ------------------------------------------------------------------------------------------------- profiles


def te_profile(input_speed_rpm: float, ratio: float, revolutions: float = 1.2, load_torque_nm: float = 0.0,
               pause_s: float = 0.5) -> list[SpeedSegment]:
    """Transmission error: ``revolutions`` output revolutions forward, a pause, as many in reverse, at a low input
    speed against a light braking load (magnitude ``load_torque_nm``, opposing each direction)."""
    duration = revolutions * ratio * 60.0 / abs(input_speed_rpm)
    load = abs(load_torque_nm)
    return [SpeedSegment(abs(input_speed_rpm), duration, -load), SpeedSegment(0.0, pause_s, 0.0),
            SpeedSegment(-abs(input_speed_rpm), duration, load), SpeedSegment(0.0, pause_s, 0.0)]


def no_load_profile(speeds_rpm: Sequence[float], dwell_s: float = 3.0, pause_s: float = 0.3) -> list[SpeedSegment]:
    """No-load running torque: each speed held ``dwell_s`` forward, then in reverse, with pauses between."""
    out: list[SpeedSegment] = []
    for n in speeds_rpm:
        out += [SpeedSegment(abs(n), dwell_s), SpeedSegment(0.0, pause_s), SpeedSegment(-abs(n), dwell_s),
                SpeedSegment(0.0, pause_s)]
    return out


def efficiency_profile(output_torque_nm: float, input_speed_rpm: float, dwell_s: float = 4.0, pause_s: float = 0.5
                       ) -> list[SpeedSegment]:
    """Efficiency: the input at ``input_speed_rpm`` forward, then in reverse, each against the loader's braking
    ``output_torque_nm`` (the rated torque)."""
    t = abs(output_torque_nm)
    n = abs(input_speed_rpm)
    return [SpeedSegment(n, dwell_s, -t), SpeedSegment(0.0, pause_s, 0.0), SpeedSegment(-n, dwell_s, t),
            SpeedSegment(0.0, pause_s, 0.0)]


def starting_profile(max_torque_nm: float, rate_nm_per_s: float, ramps: int = 3, dwell_s: float = 0.3
                     ) -> list[TorqueRamp]:
    """Starting torque: ``ramps`` slow input-torque ramps to +max and back to zero, then as many to −max (the drive
    in torque mode; a real procedure stops each ramp once the input turns)."""
    out: list[TorqueRamp] = []
    for sign in (1.0, -1.0):
        for _ in range(ramps):
            out += [TorqueRamp(sign * abs(max_torque_nm), rate_nm_per_s, 0.0),
                    TorqueRamp(0.0, 20.0 * rate_nm_per_s, dwell_s)]
    return out


# ------------------------------------------------------------------------------------------------- recording


def _speed_command(segments: Sequence[SpeedSegment], accel_rpm_per_s: float, rate_hz: float
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(time s, commanded input speed rpm, load N·m) on the sample grid: each segment's speed reached at the
    acceleration, then held for its duration."""
    times, speeds, loads = [0.0], [0.0], [0.0]
    now, speed = 0.0, 0.0
    for seg in segments:
        ramp = abs(seg.speed_rpm - speed) / accel_rpm_per_s
        times += [now + ramp, now + ramp + seg.duration_s]
        speeds += [seg.speed_rpm, seg.speed_rpm]
        loads += [seg.load_torque_nm, seg.load_torque_nm]
        now, speed = now + ramp + seg.duration_s, seg.speed_rpm
    t = np.arange(1, int(math.floor(now * rate_hz)) + 1) / rate_hz
    knots = np.array(times)
    speed_cmd = np.interp(t, knots, np.array(speeds))
    # the load follows the segment it belongs to (a step at the start of each segment's ramp)
    seg_index = np.clip(np.searchsorted(knots[2::2], t, side="left"), 0, len(segments) - 1)
    load = np.array([s.load_torque_nm for s in segments])[seg_index]
    return t, speed_cmd, load


def _integrate_rpm(time_s: np.ndarray, speed_rpm: np.ndarray) -> np.ndarray:
    """Input angle (input arcsec) from speed (rpm) by the trapezoid rule, from 0 at t = 0 (speed 0 there)."""
    dt = np.diff(time_s, prepend=0.0)
    previous = np.concatenate(([0.0], speed_rpm[:-1]))
    return np.cumsum(0.5 * (previous + speed_rpm) * dt) / 60.0 * ARCSEC_PER_REV


def _rngs(seed: int) -> list[np.random.Generator]:
    return [np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(4)]


def _read(unit: UnitPhysics, sensors: StationSensors, time_s: np.ndarray, true_in: np.ndarray,
          true_out: np.ndarray, torque_in: np.ndarray, torque_out: np.ndarray, seed: int,
          measuring_chain: MeasuringChain | None) -> dict[str, np.ndarray]:
    out_rng, in_rng, tin_rng, tout_rng = _rngs(seed)
    out_signal = (np.asarray(measuring_chain(true_out, torque_out, time_s), dtype=float) if measuring_chain is not None
                  else true_out)
    c1, s1, c2, s2 = sensors.output_encoder_graduation_arcsec
    if c1 or s1 or c2 or s2:
        rad = out_signal / ARCSEC_PER_RAD
        out_signal = out_signal + c1 * np.cos(rad) + s1 * np.sin(rad) + c2 * np.cos(2 * rad) + s2 * np.sin(2 * rad)
    output_encoder = EncoderModel(out_rng, sensors.output_encoder_noise_arcsec, sensors.output_encoder_resolution_arcsec,
                                  sensors.output_encoder_signal_period_arcsec,
                                  sensors.output_encoder_interpolation_error_arcsec)
    input_encoder = EncoderModel(in_rng, 0.0, ARCSEC_PER_REV / sensors.input_encoder_counts_per_rev, ARCSEC_PER_REV,
                                 sensors.input_encoder_error_arcsec)
    latched_in = np.interp(time_s - sensors.sync_skew_s, time_s, true_in) if sensors.sync_skew_s else true_in
    # the input encoder's once-per-turn error at its phase (the encoder model's error is a sine of the angle)
    shift = sensors.input_encoder_error_phase_rad / (2.0 * math.pi) * ARCSEC_PER_REV
    read_in = input_encoder.read(latched_in + shift) - shift
    return {
        "time_s": time_s,
        "input_angle_arcsec": read_in,
        "output_angle_arcsec": output_encoder.read(out_signal),
        "input_torque_nm": TorqueSensorModel(tin_rng, sensors.input_torque_noise_nm, sensors.input_torque_gain,
                                             sensors.input_torque_offset_nm).read(torque_in),
        "output_torque_nm": TorqueSensorModel(tout_rng, sensors.output_torque_noise_nm, sensors.output_torque_gain,
                                              sensors.output_torque_offset_nm).read(torque_out),
        "temperature_c": np.full(time_s.shape, sensors.temperature_c),
        "true_input_angle_arcsec": true_in,
        "true_output_angle_arcsec": true_out,
        "true_input_torque_nm": torque_in,
        "true_output_torque_nm": torque_out,
    }


def record_speed_run(unit: UnitPhysics, segments: Sequence[SpeedSegment], sensors: StationSensors | None = None, *,
                     seed: int = 0, accel_rpm_per_s: float = 2000.0, measuring_chain: MeasuringChain | None = None,
                     start_input_angle_arcsec: float = 0.0, batch: int = 4096) -> StationRun:
    """A run with the input drive in velocity mode (the physics fed in batches of ``batch`` samples, as the shell
    would): the commanded speed with the drive's ripple, integrated to the input angle from
    ``start_input_angle_arcsec``."""
    sensors = sensors or StationSensors()
    t, speed_cmd, load = _speed_command(segments, accel_rpm_per_s, sensors.sample_rate_hz)
    nominal = _integrate_rpm(t, speed_cmd)
    ripple = 1.0 + sensors.speed_ripple_pct / 100.0 * np.sin(
        2.0 * math.pi * sensors.speed_ripple_per_input_rev * nominal / ARCSEC_PER_REV)
    true_in = start_input_angle_arcsec + _integrate_rpm(t, speed_cmd * ripple)
    state = UnitState()
    parts = []
    for start in range(0, t.size, batch):
        sl = slice(start, start + batch)
        result, state = turn(unit, state, t[sl], true_in[sl], load[sl], sensors.temperature_c)
        parts.append(result)
    cols = _read(unit, sensors, t, true_in, np.concatenate([p.output_angle_arcsec for p in parts]),
                 np.concatenate([p.input_torque_nm for p in parts]), load, seed, measuring_chain)
    cols["input_speed_rpm"] = np.concatenate([p.input_speed_rpm for p in parts])
    return StationRun(cols, unit, sensors)


def record_torque_run(unit: UnitPhysics, ramps: Sequence[TorqueRamp], sensors: StationSensors | None = None, *,
                      seed: int = 0, measuring_chain: MeasuringChain | None = None, batch: int = 4096) -> StationRun:
    """A run with the input drive in torque mode (the starting-torque test): the commanded torque ramps, no load."""
    sensors = sensors or StationSensors()
    knots_t, knots_v, now, level = [0.0], [0.0], 0.0, 0.0
    for r in ramps:
        now += abs(r.target_nm - level) / r.rate_nm_per_s
        knots_t.append(now)
        knots_v.append(r.target_nm)
        now += r.dwell_s
        knots_t.append(now)
        knots_v.append(r.target_nm)
        level = r.target_nm
    t = np.arange(1, int(math.floor(now * sensors.sample_rate_hz)) + 1) / sensors.sample_rate_hz
    torque = np.interp(t, np.array(knots_t), np.array(knots_v))
    state = UnitState()
    parts = []
    for start in range(0, t.size, batch):
        sl = slice(start, start + batch)
        result, state = turn_with_torque(unit, state, t[sl], torque[sl], 0.0, sensors.temperature_c)
        parts.append(result)
    true_in = np.concatenate([p.input_angle_arcsec for p in parts])
    cols = _read(unit, sensors, t, true_in, np.concatenate([p.output_angle_arcsec for p in parts]), torque,
                 np.zeros_like(t), seed, measuring_chain)
    cols["input_speed_rpm"] = np.concatenate([p.input_speed_rpm for p in parts])
    return StationRun(cols, unit, sensors)


# ------------------------------------------------------------------------------------------------- truth of a run


def method_truth(unit: UnitPhysics, method: str, results: dict, temperature_c: float = 25.0) -> dict[str, float]:
    """What a turning test of ``unit`` must find, exactly, under the names of its results (the results contract of
    docs/transmission.md): the transmission error's peak-to-peak over each direction's evaluated output angles and
    the amplitudes of the unit's orders (``te_order_<k>_amplitude_arcsec``), the starting torques, the no-load
    torques at the evaluated speeds, the efficiencies at the parameters the run used (``results["parameters"]``)."""
    from tcms_daq.sim.transmission import (
        efficiency_truth,
        no_load_torque_truth,
        starting_torque_truth,
        te_peak_to_peak_truth,
    )

    out: dict[str, float] = {}
    params = results.get("parameters") or {}
    if method == "transmission-error":
        for name, d in (results.get("per_direction") or {}).items():
            out[f"{name}_transmission_error_arcsec"] = te_peak_to_peak_truth(
                unit, math.radians(d["phi_start_deg"]), math.radians(d["phi_end_deg"]))
        if out:
            out["transmission_error_arcsec"] = max(out.values())
        # each order of the unit under the name of the line found at it (within half a bin: a line's order is
        # refined off its bin), else under its own order's name (a line the evaluation did not find)
        revolutions = min((int(d["revolutions"]) for d in (results.get("per_direction") or {}).values()), default=1)
        found = [float(line["order"]) for line in results.get("te_orders") or []]
        for h in unit.harmonics:
            k = h.order_per_output_rev
            near = min(found, key=lambda f: abs(f - k), default=None)
            order = near if near is not None and abs(near - k) <= 0.5 / revolutions else k
            out[f"te_order_{order:.4g}_amplitude_arcsec"] = h.amplitude_arcsec
    elif method == "starting-torque":
        forward, reverse = starting_torque_truth(unit, 1.0), starting_torque_truth(unit, -1.0)
        out = {"forward_starting_torque_nm": forward, "reverse_starting_torque_nm": reverse,
               "starting_torque_nm": max(forward, reverse)}
    elif method == "no-load-torque":
        for n in results.get("speeds_rpm") or params.get("speeds_rpm") or []:
            n = abs(float(n))
            fwd, rev = no_load_torque_truth(unit, n, temperature_c), no_load_torque_truth(unit, -n, temperature_c)
            out[f"no_load_torque_nm@{n:g}rpm"] = 0.5 * (fwd + rev)
            out[f"forward_no_load_torque_nm@{n:g}rpm"] = fwd
            out[f"reverse_no_load_torque_nm@{n:g}rpm"] = rev
    elif method == "efficiency":
        speed, load = float(params["input_speed_rpm"]), float(params["load_torque_nm"])
        out = {"forward_efficiency": efficiency_truth(unit, load, speed, temperature_c),
               "reverse_efficiency": efficiency_truth(unit, load, -speed, temperature_c)}
    return out

"""The simulated unit turning at its input (the station's second axis): pure forward model and its exact truth.

Conventions: angles in arcsec (the input's in input arcsec), torques in N·m, speeds in rpm of the input shaft. The
output's positive direction is the one the input's positive rotation drives. ``load_torque_nm`` is the torque the
loader applies to the output (positive towards the output's positive direction, as on the stiffness bench): a
braking load on a forward rotation is negative. The reducer then transmits T_o = −load at its output.

* **Output angle** θ_out = θ_in/i + TE(φ) + twist(load): φ = θ_in/i (rad) is the kinematic output angle, TE the sum
  of the unit's harmonics A·sin(k·φ + ϕ) at orders k per output revolution (``tcms_daq.transmission.kinematics``
  names them; hidden extras from ``[sim.transmission] extra``), twist the reducer's torsion under the load from the
  stiffness bench's model (``sim.physics``: elastic, lost-motion zone, Dahl hysteresis, its state carried).
* **Input torque** (what the input drive must apply) T_in = T_o/i + μ·|T_o|/i·sgn ω + F(ω, ϑ) + J·α: the
  transmitted torque, the meshes' load-dependent loss (a share μ of it, solved from the catalogue's efficiency at
  rated torque and speed), the friction F = sgn ω·(T_c + b·|n|/1000·e^{−κ(ϑ − ϑ_ref)})·(1 ± a) (Coulomb and
  viscous parts, the viscous part thinning with the oil temperature ϑ; the negative direction a share a stiffer),
  and the inertia J of what the drive accelerates.
* **Breakaway**: at rest the input does not turn while |T_in − T_o/i| ≤ T_s(direction) (the starting torque);
  beyond it J·ω̇ = T_in − T_o/i − sgn ω·(T_c' + μ|T_o|/i) − b'·ω (exact per sample for a torque held over it) until
  ω returns to zero.

Two batched entry points, the state carried between batches (a run cut into batches gives the same result):
:func:`turn` for an input drive in velocity/position mode (the input angle is imposed: transmission error, no-load
torque, efficiency) and :func:`turn_with_torque` for one in torque mode (starting torque). The truth functions
(``*_truth``) give what an evaluation must find, exactly, from the same parameters.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from tcms_daq.sim.drive import first_order_response
from tcms_daq.sim.physics import ReducerPhysics, TwistState, physics_from_spec, twist_arcsec

from tcms_daq.config.models import BenchConfig, ExtraOrder, ReducerSpec
from tcms_daq.errors import ConfigError
from tcms_daq.transmission.kinematics import component_orders_per_output_rev, ratio
from tcms_daq.units import ARCSEC_PER_RAD, ARCSEC_PER_REV

RAD_PER_S_PER_RPM = 2.0 * math.pi / 60.0


@dataclass(frozen=True)
class TeHarmonic:
    """TE += amplitude·sin(order·φ + phase) with φ the output angle (rad); ``component`` its kinematic label
    (``pin_ring``, ``output 2×``) or None for a hidden order that belongs to no component."""

    order_per_output_rev: float
    amplitude_arcsec: float
    phase_rad: float
    component: str | None = None


@dataclass(frozen=True)
class InputFriction:
    """Friction at the input shaft (N·m): breakaway (static) and running (Coulomb + viscous per 1000 rpm at the
    reference temperature, × e^{−κ(ϑ − ϑ_ref)} elsewhere); the negative direction larger by ``asymmetry``, the
    positive smaller."""

    breakaway_nm: float
    coulomb_nm: float
    viscous_nm_per_krpm: float = 0.0
    temperature_coefficient_per_k: float = 0.03
    reference_temperature_c: float = 25.0
    asymmetry: float = 0.0

    def direction_factor(self, direction: np.ndarray | float) -> np.ndarray:
        """1 − a for the positive direction, 1 + a for the negative (1 at rest)."""
        d = np.sign(np.asarray(direction, dtype=float))
        return 1.0 - self.asymmetry * d

    def breakaway_for(self, direction: float) -> float:
        """The starting torque (N·m, magnitude) in a direction (+1 or −1)."""
        return float(self.breakaway_nm * self.direction_factor(direction))

    def viscous_nm_per_krpm_at(self, temperature_c: np.ndarray | float) -> np.ndarray:
        """The viscous coefficient at the oil temperature."""
        dt = np.asarray(temperature_c, dtype=float) - self.reference_temperature_c
        return self.viscous_nm_per_krpm * np.exp(-self.temperature_coefficient_per_k * dt)

    def running_nm(self, speed_rpm: np.ndarray | float, temperature_c: np.ndarray | float) -> np.ndarray:
        """The running friction torque at the input (signed: it opposes the speed; 0 at rest)."""
        n = np.asarray(speed_rpm, dtype=float)
        magnitude = self.coulomb_nm + self.viscous_nm_per_krpm_at(temperature_c) * np.abs(n) / 1000.0
        return np.sign(n) * magnitude * self.direction_factor(n)


@dataclass(frozen=True)
class UnitPhysics:
    """One simulated unit: ratio i, its transmission error, input friction, mesh loss share μ, input inertia J
    (kg·m²) and the torsional model of its twist under load."""

    name: str
    ratio: float
    harmonics: tuple[TeHarmonic, ...]
    friction: InputFriction
    mesh_loss: float
    input_inertia_kg_m2: float
    twist: ReducerPhysics

    def with_extra(self, extra: Sequence[ExtraOrder]) -> UnitPhysics:
        """The unit with hidden orders added (``[sim.transmission] extra``)."""
        added = tuple(TeHarmonic(e.order, e.amplitude_arcsec, math.radians(e.phase_deg), None) for e in extra)
        return replace(self, harmonics=self.harmonics + added)


@dataclass(frozen=True)
class UnitState:
    """What a batch hands the next: the last sample's time (s), input angle (input arcsec) and speed (rpm), whether
    the input sticks (torque mode), and the twist model's state."""

    time_s: float | None = None
    input_angle_arcsec: float = 0.0
    input_speed_rpm: float = 0.0
    stuck: bool = True
    twist: TwistState = field(default_factory=TwistState)


@dataclass(frozen=True)
class TurnResult:
    """One batch of the turning unit (true values): output angle (arcsec), input torque at the input shaft (N·m),
    output torque in the output shaft (the loader's torque, N·m), input angle (input arcsec), input speed (rpm)."""

    output_angle_arcsec: np.ndarray
    input_torque_nm: np.ndarray
    output_torque_nm: np.ndarray
    input_angle_arcsec: np.ndarray
    input_speed_rpm: np.ndarray


# ----------------------------------------------------------------------------------------------- construction


def unit_from_spec(spec: ReducerSpec, extra: Sequence[ExtraOrder] = ()) -> UnitPhysics:
    """The simulated unit of a catalogue entry with ``[reducers.<NAME>.sim.transmission]`` and kinematics. The mesh
    loss share μ is solved so that the efficiency at rated output torque and rated input speed, at the reference
    temperature, is the entry's ``rated_efficiency_pct`` (positive direction)."""
    sim = spec.sim.transmission
    if sim is None or spec.kinematics is None:
        raise ConfigError(f"reducers.{spec.name}: no sim.transmission (and kinematics): this unit cannot turn in the "
                          "simulation")
    teeth = spec.kinematics.teeth(spec.kind)
    i = ratio(teeth)
    orders = component_orders_per_output_rev(teeth)
    harmonics = tuple(
        TeHarmonic(h.harmonic * orders[h.component], h.amplitude_arcsec, math.radians(h.phase_deg),
                   h.component if h.harmonic == 1 else f"{h.component} {h.harmonic}×")
        for h in sim.harmonics)
    friction = InputFriction(sim.breakaway_torque_nm, sim.coulomb_torque_nm, sim.viscous_nm_per_krpm,
                             sim.viscous_temperature_coefficient_per_k, sim.reference_temperature_c,
                             sim.direction_asymmetry_pct / 100.0)
    transmitted = spec.rated_torque_nm / i
    running = float(friction.running_nm(sim.rated_input_speed_rpm, sim.reference_temperature_c))
    mesh_loss = 100.0 / sim.rated_efficiency_pct - 1.0 - running / transmitted
    if mesh_loss < 0.0:
        raise ConfigError(f"reducers.{spec.name}.sim.transmission: the friction alone costs more than "
                          f"{100 - sim.rated_efficiency_pct:g} % at rated torque and speed (no mesh loss fits)")
    unit = UnitPhysics(spec.name, i, harmonics, friction, mesh_loss, sim.input_inertia_kg_m2, physics_from_spec(spec))
    return unit.with_extra(extra)


def unit_for_bench(config: BenchConfig, catalogue: Mapping[str, ReducerSpec]) -> UnitPhysics | None:
    """The turning unit of a bench config: its ``[sim] reducer`` with ``[sim.transmission] extra`` added, or None
    when ``[sim.transmission] enabled`` is false (the stiffness bench alone)."""
    tr = config.sim.transmission
    if not tr.enabled:
        return None
    from tcms_daq.config.loader import get_reducer

    return unit_from_spec(get_reducer(dict(catalogue), config.sim.reducer, config.source_path), tr.extra)


# ----------------------------------------------------------------------------------------------- forward model


def transmission_error_arcsec(unit: UnitPhysics, output_angle_rad: np.ndarray | float) -> np.ndarray:
    """The unit's kinematic transmission error (arcsec) at output angles φ (rad): Σ A·sin(k·φ + ϕ)."""
    phi = np.asarray(output_angle_rad, dtype=float)
    out = np.zeros_like(phi)
    for h in unit.harmonics:
        out += h.amplitude_arcsec * np.sin(h.order_per_output_rev * phi + h.phase_rad)
    return out


def input_torque_nm(unit: UnitPhysics, input_speed_rpm: np.ndarray, load_torque_nm: np.ndarray,
                    temperature_c: np.ndarray | float, input_accel_rad_per_s2: np.ndarray | float = 0.0
                    ) -> np.ndarray:
    """T_in = T_o/i + μ·|T_o|/i·sgn ω + F(ω, ϑ) + J·α with T_o = −load (module docstring)."""
    n = np.asarray(input_speed_rpm, dtype=float)
    transmitted = -np.asarray(load_torque_nm, dtype=float) / unit.ratio
    return (transmitted + unit.mesh_loss * np.abs(transmitted) * np.sign(n)
            + unit.friction.running_nm(n, temperature_c) + unit.input_inertia_kg_m2 * np.asarray(input_accel_rad_per_s2))


def _output(unit: UnitPhysics, state: UnitState, input_angle: np.ndarray, load: np.ndarray
            ) -> tuple[np.ndarray, TwistState]:
    phi_rad = input_angle / unit.ratio / ARCSEC_PER_RAD
    twist, twist_state = twist_arcsec(load, unit.twist, state.twist)
    return input_angle / unit.ratio + transmission_error_arcsec(unit, phi_rad) + twist, twist_state


def _as_batch(time_s, *arrays) -> tuple[np.ndarray, ...]:
    t = np.asarray(time_s, dtype=float).ravel()
    return (t, *(np.broadcast_to(np.asarray(a, dtype=float), t.shape).astype(float) for a in arrays))


def turn(unit: UnitPhysics, state: UnitState, time_s, input_angle_arcsec, load_torque_nm, temperature_c=25.0
         ) -> tuple[TurnResult, UnitState]:
    """The unit driven at an imposed input angle (the input drive in velocity or position mode), one batch.

    Arrays of one length (scalars broadcast): time (s, increasing), input angle (input arcsec), the loader's
    torque (N·m), the oil temperature (°C). The input speed and acceleration are backward differences (the first
    sample's from the state's last sample; at the very first sample of a run, rest)."""
    t, angle, load, temperature = _as_batch(time_s, input_angle_arcsec, load_torque_nm, temperature_c)
    if t.size == 0:
        e = np.empty(0)
        return TurnResult(e, e, e, e, e), state
    t_prev = state.time_s if state.time_s is not None else t[0]
    a_prev = state.input_angle_arcsec if state.time_s is not None else angle[0]
    dt = np.diff(t, prepend=t_prev)
    dt = np.where(dt > 0, dt, np.inf)
    speed_rpm = np.diff(angle, prepend=a_prev) / ARCSEC_PER_REV / dt * 60.0
    accel = np.diff(speed_rpm, prepend=state.input_speed_rpm) * RAD_PER_S_PER_RPM / dt
    output, twist_state = _output(unit, state, angle, load)
    torque_in = input_torque_nm(unit, speed_rpm, load, temperature, accel)
    new_state = UnitState(float(t[-1]), float(angle[-1]), float(speed_rpm[-1]), bool(speed_rpm[-1] == 0.0),
                          twist_state)
    return TurnResult(output, torque_in, load.copy(), angle, speed_rpm), new_state


def turn_with_torque(unit: UnitPhysics, state: UnitState, time_s, input_torque_nm_, load_torque_nm,
                     temperature_c=25.0) -> tuple[TurnResult, UnitState]:
    """The unit driven by an imposed input torque (the input drive in torque mode: the starting-torque test), one
    batch: the input sticks while the torque beyond the transmitted one stays within the breakaway torque, then
    turns under J·ω̇ = T_in − T_o/i − sgn·(T_c' + μ|T_o|/i) − b'·ω until it stops again (module docstring). The
    torque is taken as held over each sample interval (it applies from the previous sample to this one)."""
    t, torque, load, temperature = _as_batch(time_s, input_torque_nm_, load_torque_nm, temperature_c)
    n = t.size
    if n == 0:
        e = np.empty(0)
        return TurnResult(e, e, e, e, e), state
    t_prev = state.time_s if state.time_s is not None else t[0]
    dt = np.diff(t, prepend=t_prev)
    transmitted = -load / unit.ratio
    net = torque - transmitted  # what turns the input against its friction and loss
    speed = np.zeros(n)  # rad/s
    f = unit.friction
    j = unit.input_inertia_kg_m2
    omega0 = state.input_speed_rpm * RAD_PER_S_PER_RPM
    stuck = state.stuck
    k = 0
    while k < n:
        if stuck:
            over = np.flatnonzero(np.abs(net[k:]) > f.breakaway_nm * f.direction_factor(net[k:]))
            if over.size == 0:
                break
            k += int(over[0])
            omega0, stuck = 0.0, False
        direction = float(np.sign(net[k]) if omega0 == 0.0 else np.sign(omega0))
        factor = float(f.direction_factor(direction))
        viscous = float(np.mean(f.viscous_nm_per_krpm_at(temperature[k:]))) * factor / 1000.0 / RAD_PER_S_PER_RPM
        drive = net[k:] - direction * (f.coulomb_nm * factor + unit.mesh_loss * np.abs(transmitted[k:]))
        seg = _linear_speed(drive, dt[k:], j, viscous, omega0)
        ends = np.flatnonzero(direction * seg <= 0.0)
        end = k + (int(ends[0]) if ends.size else seg.size)
        speed[k:end] = seg[: end - k]
        if end >= n:
            break
        k, omega0, stuck = end, 0.0, True
    previous = np.concatenate(([state.input_speed_rpm * RAD_PER_S_PER_RPM], speed[:-1]))
    angle_step = 0.5 * (previous + speed) * dt
    angle = state.input_angle_arcsec + np.cumsum(angle_step) * ARCSEC_PER_RAD
    output, twist_state = _output(unit, state, angle, load)
    speed_rpm = speed / RAD_PER_S_PER_RPM
    new_state = UnitState(float(t[-1]), float(angle[-1]), float(speed_rpm[-1]), bool(speed[-1] == 0.0), twist_state)
    return TurnResult(output, torque, load.copy(), angle, speed_rpm), new_state


def _linear_speed(drive_nm: np.ndarray, dt_s: np.ndarray, inertia: float, viscous_nm_s: float, omega0: float
                  ) -> np.ndarray:
    """ω_n of J·ω̇ + b·ω = u_n over each interval (u held), from ω = omega0: exact per sample; the intervals after
    the first must be equal (a batch of the simulated clock)."""
    if viscous_nm_s <= 0.0:
        return omega0 + np.cumsum(drive_nm * dt_s) / inertia
    out = np.empty(drive_nm.size)
    a0 = math.exp(-viscous_nm_s * dt_s[0] / inertia)
    out[0] = a0 * omega0 + (1.0 - a0) * drive_nm[0] / viscous_nm_s
    if drive_nm.size > 1:
        step = float(dt_s[1])
        if not np.allclose(dt_s[1:], step, rtol=1e-6, atol=0.0):
            raise ValueError("turn_with_torque needs equally spaced samples within a batch")
        decay = viscous_nm_s * step / inertia
        a = math.exp(-decay)
        out[1:] = first_order_response((1.0 - a) * drive_nm[1:] / viscous_nm_s, a, float(out[0]), decay)
    return out


# ----------------------------------------------------------------------------------------------- truth


def te_peak_to_peak_truth(unit: UnitPhysics, start_rad: float = 0.0, end_rad: float = 2.0 * math.pi,
                          points: int = 1 << 18) -> float:
    """Peak-to-peak (arcsec) of the unit's transmission error over output angles [start, end] (rad), on a grid fine
    enough for every order (then refined around the extremes)."""
    phi = np.linspace(start_rad, end_rad, points)
    te = transmission_error_arcsec(unit, phi)
    step = phi[1] - phi[0]
    out = []
    for index, sign in ((int(np.argmax(te)), 1.0), (int(np.argmin(te)), -1.0)):
        fine = np.linspace(phi[index] - step, phi[index] + step, 201)
        out.append(sign * float(np.max(sign * transmission_error_arcsec(unit, fine))))
    return out[0] - out[1]


def no_load_torque_truth(unit: UnitPhysics, input_speed_rpm: float, temperature_c: float) -> float:
    """The running torque (N·m, magnitude) at a constant input speed with no load, in the speed's direction."""
    return abs(float(unit.friction.running_nm(input_speed_rpm, temperature_c)))


def starting_torque_truth(unit: UnitPhysics, direction: float) -> float:
    """The starting (breakaway) torque (N·m, magnitude) at no load in a direction (+1, −1)."""
    return unit.friction.breakaway_for(direction)


def efficiency_truth(unit: UnitPhysics, output_torque_nm: float, input_speed_rpm: float, temperature_c: float
                     ) -> float:
    """Output power / input power at a constant input speed (its sign the direction) against a braking load of
    ``output_torque_nm`` (magnitude): T_o/(i·T_in) with T_in of :func:`input_torque_nm`."""
    direction = math.copysign(1.0, input_speed_rpm)
    load = -direction * abs(output_torque_nm)
    t_in = float(input_torque_nm(unit, np.array([input_speed_rpm]), np.array([load]), temperature_c)[0])
    return abs(output_torque_nm) / (unit.ratio * abs(t_in))

"""The second axis's physics as the simulated instruments see it: the input shaft turned by the input drive, the
output turned through the reducer, the torque at the input. The instruments (the input drive, the input AED, the
ND 287 in coupled mode, the two-axis counter card) read it through :class:`DriveTrainPhysics`, a narrow Protocol,
so a richer model replaces :class:`RigidDriveTrain` in one line where ``InstrumentSimulators`` builds it:
:class:`UnitDriveTrain`, the core's turning unit (``sim.transmission``: transmission-error harmonics, mesh losses,
friction with breakaway) when the bench config has ``[sim.transmission] enabled``.

Time is the simulated clock of ``SharedPhysics`` (s). Sign conventions: a positive input velocity turns the output
positive; the output angle here is the rotation the input drives through the reducer (arcsec), without the
torsional twist under the loader's torque that the bench physics (``sim.bench``) adds on top; the input torque is
what the input drive delivers into the reducer's input (N·m), positive in the positive direction of rotation.
"""

from __future__ import annotations

import bisect
import math
import threading
from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol, runtime_checkable

import numpy as np
import numpy.typing as npt
from tcms_daq.sim.transmission import input_torque_nm, transmission_error_arcsec

from tcms_daq.units import ARCSEC_PER_DEG

if TYPE_CHECKING:
    from tcms_daq.sim.transmission import UnitPhysics

    from tcms_daq.config.models import BenchConfig, ReducerSpec

HISTORY_S = 2.0  # how far back in simulated time the angles can be asked for (a counter card latches in the past)


@runtime_checkable
class DriveTrainPhysics(Protocol):
    """What the second axis's simulated instruments read. ``command`` is called on every physics tick with what the
    input drive and the loader do at ``time_s``; the readers may ask for any time since the previous commands
    (within ``HISTORY_S``) or after the last."""

    def command(self, time_s: float, input_velocity_deg_per_s: float, loader_torque_nm: float) -> None:
        """From ``time_s`` on: the input turns at ``input_velocity_deg_per_s``, the loader applies
        ``loader_torque_nm`` to the output."""
        ...

    def input_angle_deg(self, time_s: float) -> float:
        """The input shaft's angle (deg; 0 where the simulation started)."""
        ...

    def output_angle_arcsec(self, time_s: float) -> float:
        """The output's rotation driven from the input through the reducer (arcsec)."""
        ...

    def input_torque_nm(self, time_s: float) -> float:
        """The torque the input drive delivers into the reducer's input (N·m)."""
        ...

    def input_angles_deg(self, time_s: np.ndarray) -> np.ndarray:
        """``input_angle_deg`` at many times at once (a counter card's latches)."""
        ...

    def output_angles_arcsec(self, time_s: np.ndarray) -> np.ndarray:
        """``output_angle_arcsec`` at many times at once."""
        ...


@dataclass(frozen=True)
class _Segment:
    time_s: float
    angle_deg: float
    velocity_deg_per_s: float
    loader_torque_nm: float


class RigidDriveTrain:
    """A rigid reducer of ratio ``ratio`` (input revolutions per output revolution) with Coulomb and viscous
    friction at the input:

        θ_out = θ_in / i                      (no transmission error)
        T_in  = −T_loader / i + sign(ω_in)·T_c + c_v·ω_in      (ω_in in deg/s; at rest: −T_loader / i)

    The angle is integrated exactly over piecewise-constant velocities (one segment per ``command``)."""

    def __init__(self, ratio: float, *, coulomb_friction_nm: float = 0.0,
                 viscous_friction_nm_per_deg_per_s: float = 0.0, rest_window_deg_per_s: float = 1e-6):
        if not (math.isfinite(ratio) and ratio != 0.0):
            raise ValueError(f"reducer ratio must be finite and non-zero, got {ratio!r}")
        if coulomb_friction_nm < 0 or viscous_friction_nm_per_deg_per_s < 0:
            raise ValueError("friction must be >= 0")
        self.ratio = float(ratio)
        self.coulomb_friction_nm = float(coulomb_friction_nm)
        self.viscous_friction_nm_per_deg_per_s = float(viscous_friction_nm_per_deg_per_s)
        self.rest_window_deg_per_s = float(rest_window_deg_per_s)
        self._lock = threading.Lock()
        self._segments: list[_Segment] = [_Segment(0.0, 0.0, 0.0, 0.0)]
        self._times: list[float] = [0.0]

    def command(self, time_s: float, input_velocity_deg_per_s: float, loader_torque_nm: float) -> None:
        with self._lock:
            last = self._segments[-1]
            if time_s < last.time_s:
                return  # never rewrite the past
            angle = last.angle_deg + last.velocity_deg_per_s * (time_s - last.time_s)
            segment = _Segment(float(time_s), angle, float(input_velocity_deg_per_s), float(loader_torque_nm))
            if time_s == last.time_s:
                self._segments[-1] = segment
            else:
                self._segments.append(segment)
                self._times.append(float(time_s))
            cut = bisect.bisect_left(self._times, time_s - HISTORY_S) - 1
            if cut > 0:
                del self._segments[:cut], self._times[:cut]

    def _segment(self, time_s: float) -> _Segment:
        with self._lock:
            index = max(0, bisect.bisect_right(self._times, time_s) - 1)
            return self._segments[index]

    def input_angle_deg(self, time_s: float) -> float:
        seg = self._segment(time_s)
        return seg.angle_deg + seg.velocity_deg_per_s * (time_s - seg.time_s)

    def output_angle_arcsec(self, time_s: float) -> float:
        return self.input_angle_deg(time_s) / self.ratio * ARCSEC_PER_DEG

    def input_angles_deg(self, time_s: np.ndarray) -> np.ndarray:
        t = np.asarray(time_s, dtype=float)
        with self._lock:
            starts = np.array(self._times)
            segments = np.array([(s.angle_deg, s.velocity_deg_per_s) for s in self._segments])
        index = np.maximum(np.searchsorted(starts, t, side="right") - 1, 0)  # bisect_right, as _segment
        return segments[index, 0] + segments[index, 1] * (t - starts[index])

    def output_angles_arcsec(self, time_s: np.ndarray) -> np.ndarray:
        return self.input_angles_deg(time_s) / self.ratio * ARCSEC_PER_DEG

    def input_velocity_deg_per_s(self, time_s: float) -> float:
        return self._segment(time_s).velocity_deg_per_s

    def input_torque_nm(self, time_s: float) -> float:
        seg = self._segment(time_s)
        velocity = seg.velocity_deg_per_s
        torque = -seg.loader_torque_nm / self.ratio
        if abs(velocity) > self.rest_window_deg_per_s:
            torque += math.copysign(self.coulomb_friction_nm, velocity) + self.viscous_friction_nm_per_deg_per_s * velocity
        return torque


# ------------------------------------------------------------------------------------------------ the turning unit

#: a catch-up older than this many time constants is over (its lag e^{-u}·(1 + …) below 1e-10 of its start)
_CATCH_UP_DONE = 30.0
#: the shaft sticks again once the command has rested a whole tick and the lag left is below this (deg)
_REST_LAG_DEG = 1e-6


@dataclass(frozen=True)
class _CatchUp:
    """The shaft broke away at ``time_s`` with ``lag_deg`` (command − shaft) and catches the command up:
    lag(t) = L·g(u), g(u) = (1 + (1 + c)·u)·e^{−u}, u = (t − t_b)/τ, c = ω_b·τ/L (the shaft starts from rest:
    its velocity ω_cmd − L·g'(u)/τ is 0 at u = 0, its acceleration L(1 + 2c)/τ² > 0: a critically damped loop)."""

    time_s: float
    lag_deg: float
    c: float


@dataclass(frozen=True)
class _UnitPiece:
    """From ``time_s`` to the next piece: the commanded angle (deg) and velocity (deg/s), the command's acceleration
    (deg/s², J·α), the loader's torque (N·m), and the shaft: stuck at ``shaft_deg`` (breaking away at
    ``breakaway_s`` within the piece, or not), or following the command (catching up from ``catch_up``)."""

    time_s: float
    command_deg: float
    velocity_deg_per_s: float
    accel_deg_per_s2: float
    loader_torque_nm: float
    stuck: bool
    shaft_deg: float = 0.0
    breakaway_s: float | None = None
    catch_up: _CatchUp | None = None


class UnitDriveTrain:
    """The simulated unit of ``sim.transmission`` turned by the input drive in profile velocity (the core's
    ``UnitPhysics``: its transmission error, mesh loss, friction with breakaway, inertia; ``[sim.transmission]``),
    queried at any time like :class:`RigidDriveTrain` (the commands are piecewise-constant velocities).

    * **The shaft** follows the commanded angle (a stiff velocity loop) while it turns. At rest it sticks: the
      drive's torque then grows with the angle the shaft lags behind the command, ``holding_stiffness`` N·m per
      degree (a creep command ramps the torque at stiffness × velocity), until the torque beyond the transmitted one
      exceeds the unit's breakaway torque in that direction; the shaft then catches the command up, critically
      damped in ``catch_up_time_constant_s`` from rest (:class:`_CatchUp`). It sticks again when the command has
      been at rest for a whole tick and the catch-up is over. The drive's speed ripple (a share of the speed at an
      order per input revolution) moves the shaft by r·360°/(2πm)·(1 − cos(2πm·θ/360°)).
    * **The output** turns by θ_in/i + TE(θ_in/i) (``sim.transmission.transmission_error_arcsec``); the twist under
      the loader's torque is the bench physics' (``sim.bench``), added by whoever reads the output encoder.
    * **The input torque** while turning is ``sim.transmission.input_torque_nm`` (transmitted, mesh loss, friction at
      the speed and the oil temperature, J·α); while stuck, the transmitted torque plus the drive's holding torque.
    """

    def __init__(self, unit: UnitPhysics, *, temperature_c: float = 25.0, holding_stiffness_nm_per_deg: float = 5.0,
                 catch_up_time_constant_s: float = 0.02, speed_ripple_pct: float = 0.0,
                 speed_ripple_per_input_rev: float = 1.0, start_s: float = 0.0, start_deg: float = 0.0):
        """``start_s``/``start_deg``: the simulated time the unit is mounted and its input's angle then (at rest)."""
        if not holding_stiffness_nm_per_deg > 0 or not catch_up_time_constant_s > 0:
            raise ValueError("holding stiffness and catch-up time constant must be > 0")
        self.unit = unit
        self.ratio = float(unit.ratio)
        self.temperature_c = float(temperature_c)
        self.stiffness = float(holding_stiffness_nm_per_deg)
        self.tau_s = float(catch_up_time_constant_s)
        self.ripple = float(speed_ripple_pct) / 100.0
        self.ripple_order = float(speed_ripple_per_input_rev)
        self._lock = threading.Lock()
        self._pieces: list[_UnitPiece] = [_UnitPiece(float(start_s), float(start_deg), 0.0, 0.0, 0.0, True,
                                                     float(start_deg))]
        self._times: list[float] = [float(start_s)]

    @classmethod
    def for_bench(cls, config: BenchConfig, reducer: ReducerSpec | None = None,
                  catalogue: Mapping[str, ReducerSpec] | None = None, *, start_s: float = 0.0,
                  start_deg: float = 0.0) -> UnitDriveTrain | None:
        """The drivetrain of a bench config's ``[sim.transmission]`` (None when it is not enabled): the unit of
        ``reducer`` (default the config's ``[sim] reducer`` in ``catalogue``, default the config's catalogue) with
        the hidden extra orders."""
        from tcms_daq.sim.transmission import unit_for_bench, unit_from_spec

        from tcms_daq.config.loader import load_reducers_for

        tr = config.sim.transmission
        if not tr.enabled:
            return None
        unit = (unit_from_spec(reducer, tr.extra) if reducer is not None
                else unit_for_bench(config, catalogue if catalogue is not None else load_reducers_for(config)))
        if unit is None:  # pragma: no cover - enabled was checked
            return None
        return cls(unit, temperature_c=tr.temperature_c, holding_stiffness_nm_per_deg=tr.holding_stiffness_nm_per_deg,
                   catch_up_time_constant_s=tr.catch_up_time_constant_s, speed_ripple_pct=tr.speed_ripple_pct,
                   speed_ripple_per_input_rev=tr.speed_ripple_per_input_rev, start_s=start_s, start_deg=start_deg)

    # -- the state ---------------------------------------------------------------------------------------------------

    def _breakaway_lags(self) -> tuple[float, float]:
        """(positive, negative) lag (deg) at which the drive's holding torque breaks the shaft away."""
        f = self.unit.friction
        return f.breakaway_for(1.0) / self.stiffness, -f.breakaway_for(-1.0) / self.stiffness

    def _stuck_piece(self, time_s: float, command_deg: float, velocity: float, accel: float, load: float,
                     shaft_deg: float) -> _UnitPiece:
        up, down = self._breakaway_lags()
        lag = command_deg - shaft_deg
        breakaway = None
        if velocity > 0:
            breakaway = time_s + max(0.0, (up - lag) / velocity)
        elif velocity < 0:
            breakaway = time_s + max(0.0, (down - lag) / velocity)
        return _UnitPiece(time_s, command_deg, velocity, accel, load, True, shaft_deg, breakaway)

    def _catch_up_at(self, piece: _UnitPiece) -> _CatchUp | None:
        """The catch-up a stuck piece starts at its breakaway."""
        assert piece.breakaway_s is not None
        lag = piece.command_deg + piece.velocity_deg_per_s * (piece.breakaway_s - piece.time_s) - piece.shaft_deg
        if lag == 0.0:
            return None
        return _CatchUp(piece.breakaway_s, lag, piece.velocity_deg_per_s * self.tau_s / lag)

    def _after(self, piece: _UnitPiece, time_s: float) -> tuple[bool, float, _CatchUp | None]:
        """(stuck, stuck shaft angle, catch-up) of ``piece`` at ``time_s`` (within it or at its end)."""
        if piece.stuck and (piece.breakaway_s is None or time_s < piece.breakaway_s):
            return True, piece.shaft_deg, None
        catch = self._catch_up_at(piece) if piece.stuck else piece.catch_up
        if catch is not None and (time_s - catch.time_s) / self.tau_s > _CATCH_UP_DONE:
            catch = None
        return False, 0.0, catch

    def _lag(self, catch: _CatchUp | None, time_s: float) -> float:
        """What the shaft still lags behind the command at ``time_s`` (deg; 0 without a catch-up)."""
        if catch is None:
            return 0.0
        u = max(0.0, (time_s - catch.time_s) / self.tau_s)
        return catch.lag_deg * (1.0 + (1.0 + catch.c) * u) * math.exp(-u)

    def command(self, time_s: float, input_velocity_deg_per_s: float, loader_torque_nm: float) -> None:
        with self._lock:
            last = self._pieces[-1]
            if time_s < last.time_s:
                return  # never rewrite the past
            # a command at the last piece's time replaces it: the state comes from the piece before (if any)
            base = self._pieces[-2] if time_s == last.time_s and len(self._pieces) > 1 else last
            span = time_s - base.time_s
            command = base.command_deg + base.velocity_deg_per_s * span
            velocity = float(input_velocity_deg_per_s)
            accel = (velocity - base.velocity_deg_per_s) / span if span > 0 else 0.0
            stuck, shaft, catch = self._after(base, time_s)
            if (not stuck and velocity == 0.0 and base.velocity_deg_per_s == 0.0
                    and abs(self._lag(catch, time_s)) < _REST_LAG_DEG):
                stuck, shaft = True, command  # at rest a whole tick with the catch-up over: it sticks
            piece = (self._stuck_piece(time_s, command, velocity, accel, float(loader_torque_nm), shaft) if stuck
                     else _UnitPiece(time_s, command, velocity, accel, float(loader_torque_nm), False, 0.0, None,
                                     catch))
            if time_s == last.time_s:
                self._pieces[-1] = piece
            else:
                self._pieces.append(piece)
                self._times.append(float(time_s))
            cut = bisect.bisect_left(self._times, time_s - HISTORY_S) - 1
            if cut > 0:
                del self._pieces[:cut], self._times[:cut]

    # -- queries (vectorised over times; the scalar Protocol methods below) -----------------------------------------

    def _groups(self, time_s: np.ndarray) -> list[tuple[_UnitPiece, np.ndarray]]:
        with self._lock:
            times = np.asarray(self._times)
            pieces = list(self._pieces)
        index = np.clip(np.searchsorted(times, time_s, side="right") - 1, 0, len(pieces) - 1)
        return [(pieces[k], index == k) for k in np.unique(index)]

    def _shaft(self, piece: _UnitPiece, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(model shaft angle deg, velocity deg/s, acceleration deg/s², stuck) at times ``t`` of one piece."""
        command = piece.command_deg + piece.velocity_deg_per_s * (t - piece.time_s)
        if piece.stuck:
            stuck = t < (piece.breakaway_s if piece.breakaway_s is not None else np.inf)
            catch = self._catch_up_at(piece) if piece.breakaway_s is not None else None
        else:
            stuck = np.zeros(t.shape, dtype=bool)
            catch = piece.catch_up
        shaft = np.where(stuck, piece.shaft_deg, command)
        velocity = np.where(stuck, 0.0, piece.velocity_deg_per_s)
        accel = np.where(stuck, 0.0, piece.accel_deg_per_s2)
        if catch is not None:
            u = np.clip((t - catch.time_s) / self.tau_s, 0.0, None)
            e = np.exp(-u)
            g = (1.0 + (1.0 + catch.c) * u) * e
            g1 = (catch.c - (1.0 + catch.c) * u) * e
            g2 = ((1.0 + catch.c) * u - (1.0 + 2.0 * catch.c)) * e
            moving = ~stuck
            shaft = np.where(moving, command - catch.lag_deg * g, shaft)
            velocity = np.where(moving, velocity - catch.lag_deg * g1 / self.tau_s, velocity)
            accel = np.where(moving, accel - catch.lag_deg * g2 / self.tau_s**2, accel)
        return shaft, velocity, accel, stuck

    def _ripple_deg(self, shaft_deg: np.ndarray) -> np.ndarray:
        if self.ripple == 0.0:
            return np.zeros_like(shaft_deg)
        m = self.ripple_order
        return self.ripple * 360.0 / (2.0 * math.pi * m) * (1.0 - np.cos(2.0 * math.pi * m * shaft_deg / 360.0))

    def state_at(self, time_s: npt.ArrayLike, loader_torque_nm: npt.ArrayLike | None = None
                 ) -> dict[str, np.ndarray]:
        """At times (s): ``input_angle_deg``, ``input_speed_rpm``, ``output_rotation_arcsec`` (θ_in/i + TE),
        ``input_torque_nm`` (with the loader's torque of each time when given, else its piece's), ``stuck``."""
        t = np.atleast_1d(np.asarray(time_s, dtype=float))
        loads = None if loader_torque_nm is None else np.broadcast_to(np.asarray(loader_torque_nm, float), t.shape)
        angle, speed, torque = np.empty(t.shape), np.empty(t.shape), np.empty(t.shape)
        stuck_all = np.empty(t.shape, dtype=bool)
        for piece, sel in self._groups(t):
            shaft, velocity, accel, stuck = self._shaft(piece, t[sel])
            wave = 2.0 * math.pi * self.ripple_order * shaft / 360.0
            actual = shaft + self._ripple_deg(shaft)
            velocity = velocity * (1.0 + self.ripple * np.sin(wave))
            load = loads[sel] if loads is not None else np.full(shaft.shape, piece.loader_torque_nm)
            speed_rpm = velocity / 6.0
            turning = input_torque_nm(self.unit, speed_rpm, load, self.temperature_c,
                                      np.radians(accel))
            holding = -load / self.ratio + self.stiffness * (piece.command_deg + piece.velocity_deg_per_s
                                                             * (t[sel] - piece.time_s) - piece.shaft_deg)
            angle[sel], speed[sel], torque[sel] = actual, speed_rpm, np.where(stuck, holding, turning)
            stuck_all[sel] = stuck
        phi_rad = np.radians(angle) / self.ratio
        rotation = angle * ARCSEC_PER_DEG / self.ratio + transmission_error_arcsec(self.unit, phi_rad)
        return {"input_angle_deg": angle, "input_speed_rpm": speed, "output_rotation_arcsec": rotation,
                "input_torque_nm": torque, "stuck": stuck_all}

    def input_angle_deg(self, time_s: float) -> float:
        return float(self.state_at(time_s)["input_angle_deg"][0])

    def output_angle_arcsec(self, time_s: float) -> float:
        return float(self.state_at(time_s)["output_rotation_arcsec"][0])

    def input_angles_deg(self, time_s: np.ndarray) -> np.ndarray:
        return self.state_at(time_s)["input_angle_deg"]

    def output_angles_arcsec(self, time_s: np.ndarray) -> np.ndarray:
        return self.state_at(time_s)["output_rotation_arcsec"]

    def input_torque_nm(self, time_s: float) -> float:
        return float(self.state_at(time_s)["input_torque_nm"][0])

    def input_velocity_deg_per_s(self, time_s: float) -> float:
        return float(self.state_at(time_s)["input_speed_rpm"][0]) * 6.0

"""The second axis's physics as the simulated instruments see it: the input shaft turned by the input drive, the
output turned through the reducer, the torque at the input. The instruments (the input drive, the input AED, the
ND 287 in coupled mode, the two-axis counter card) read it through :class:`DriveTrainPhysics`, a narrow Protocol,
so a richer model (transmission-error harmonics, mesh losses: the core's ``sim`` physics) replaces
:class:`RigidDriveTrain` in one line where ``InstrumentSimulators`` builds it.

Time is the simulated clock of ``SharedPhysics`` (s). Sign conventions: a positive input velocity turns the output
positive; the output angle here is the rotation the input drives through the reducer (arcsec), without the
torsional twist under the loader's torque that the bench physics (``sim.bench``) adds on top; the input torque is
what the input drive delivers into the reducer's input (N·m), positive in the positive direction of rotation.
"""

from __future__ import annotations

import bisect
import math
import threading
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

from tcms_daq.units import ARCSEC_PER_DEG

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

    def input_velocity_deg_per_s(self, time_s: float) -> float:
        return self._segment(time_s).velocity_deg_per_s

    def input_torque_nm(self, time_s: float) -> float:
        seg = self._segment(time_s)
        velocity = seg.velocity_deg_per_s
        torque = -seg.loader_torque_nm / self.ratio
        if abs(velocity) > self.rest_window_deg_per_s:
            torque += math.copysign(self.coulomb_friction_nm, velocity) + self.viscous_friction_nm_per_deg_per_s * velocity
        return torque

"""The turning tests' procedure: the stiffness test's state machine (``TestRun``) with the input drive.

    idle → preparing (loader and input drive reset, both torque channels tared, both enabled)
         → loading (the method plan's steps: the loader's torque, then the input's velocity, held; or a creep until
           the input breaks away) → evaluating → completed | aborted | failed

While it runs the acquisition serves it in station mode (``tcms_daq.acquisition.station``): the angle pair source is
the time base, the loader's torque and the input torque are interpolated onto its pairs, and the second axis's
channels are judged as the loader's are (watchdog, errors, the input drive's faults: ``drive_fault``, its lost link:
``lost_instrument``). On every exit path, before the loader's ramp to zero, the input drive is brought to rest and
disabled (``Bench.stop_input_drive``) and the procedure waits until it no longer turns; a lost input drive is left to
its own watchdog. Times are the bench clock's, so on the simulated clock a run takes no real time.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from tcms_daq.acquisition.bench import Bench
from tcms_daq.acquisition.interlocks import InterlockLimits
from tcms_daq.acquisition.loop import AcquisitionLoop
from tcms_daq.acquisition.record import LOADING
from tcms_daq.acquisition.testrun import Evaluator, ProcedureError, ProcedureOptions, TestRun, default_limits
from tcms_daq.drivers.base import InputDriveStatus
from tcms_daq.procedure.methods import CreepStep, MethodPlan, SpeedStep
from tcms_daq.procedure.profiles import Segment
from tcms_daq.protocols.cia402 import POWERED_STATES

SPEED_TOLERANCE = 0.05  # the input's measured speed within this share of its target at the end of a step
STOP_WAIT_S = 3.0  # beyond the deceleration time, how long the input may take to come to rest on exit
TURN_TIMEOUT_S = 2.0  # beyond twice a step's duration, how long the input may take to turn the step's angle
STEP_COLUMN = "step_index"


def loader_segments(plan: MethodPlan) -> list[Segment]:
    """The loader's torque changes of a method plan as profile segments (for the limits and their check): each
    change of the load at the plan's slope, held for its step (at least one segment: zero)."""
    out: list[Segment] = []
    level = 0.0
    for step in plan.steps:
        if isinstance(step, SpeedStep) and step.load_torque_nm != level:
            out.append(Segment(step.load_torque_nm, plan.load_slope_nm_per_s, step.duration_s, -1))
            level = step.load_torque_nm
    return out or [Segment(0.0, plan.load_slope_nm_per_s, 0.0, -1)]


def method_limits(bench: Bench, plan: MethodPlan, reducer_torque_limit_nm: float | None) -> InterlockLimits:
    """The interlock limits of a turning test: the stiffness test's for its loader segments; no angle window (the
    output turns)."""
    limits = default_limits(bench, loader_segments(plan), reducer_torque_limit_nm)
    return InterlockLimits(**{**limits.to_dict(), "angle_min_arcsec": None, "angle_max_arcsec": None})


class MethodRun(TestRun):
    """One turning test (``tcms_daq.procedure.methods.MethodPlan``) on a bench with its second axis; ``evaluate``
    gets the run's samples (every column of the station's time base) and returns the results dict."""

    def __init__(self, bench: Bench, plan: MethodPlan, *, reducer_torque_limit_nm: float | None = None,
                 evaluate: Evaluator | None = None, options: ProcedureOptions | None = None, **kwargs: Any):
        missing = [kind for kind in ("input_drive", "input_angle") if getattr(bench, kind) is None]
        if missing:
            raise ProcedureError(f"{plan.method} needs the bench's {' and '.join(missing)}")
        self.method_plan = plan
        segments = loader_segments(plan)
        limits = kwargs.pop("limits", None) or method_limits(bench, plan, reducer_torque_limit_nm)
        info = {**plan.to_dict(), **kwargs.pop("profile_info", {})}
        super().__init__(bench, segments, limits=limits, evaluate=evaluate, options=options, profile_info=info,
                         **kwargs)
        peak = max((abs(s.target_nm) for s in segments), default=0.0)
        self.tolerance_nm = (self.options.tolerance_nm if self.options.tolerance_nm is not None
                             else max(0.02 * peak, 2.0))
        self._velocity_deg_per_s = 0.0
        self._input_stopped = False
        self._step_marks: list[tuple[float, int]] = []

    # -- the acquisition in station mode ----------------------------------------------------------------------
    def _station(self, acq: AcquisitionLoop, active: bool) -> None:
        acq.station.set_active(active)

    # -- the phases ---------------------------------------------------------------------------------------------
    def _prepare(self, acq: AcquisitionLoop) -> None:
        drive = self.bench.input_drive
        assert drive is not None
        status: InputDriveStatus = acq.station.drive_command(drive.status)
        if status.state in POWERED_STATES:
            raise ProcedureError(f"{drive.name} is {status.state} at {status.velocity_deg_per_s:.1f} deg/s before the "
                                 "test: not taken over")
        if status.fault:
            self.record.notes.append(f"input drive was in FAULT (0x{status.error_code:04X}) before the test: reset")
            acq.station.drive_command(drive.fault_reset)
        super()._prepare(acq)  # the loader: fault reset, torque tare, enable; the input at rest and unloaded
        if self.bench.input_torque is not None:
            acq.instrument_command("input_torque", self.bench.input_torque.tare)
        acq.station.drive_command(drive.enable)
        acq.station.armed = True
        acq.wait(self.options.settle_s, abort_event=self.abort_event)

    def _load(self, acq: AcquisitionLoop) -> None:
        self._transition(LOADING)
        plan = self.method_plan
        t_start = acq.clock.now()
        durations = plan.step_durations_s()
        for number, step in enumerate(plan.steps):
            now = acq.clock.now()
            acq.fanout.publish_event("method_progress", now, run_id=self.run_id, method=plan.method, step=number,
                                     steps=len(plan.steps), step_name=step.phase, elapsed_s=now - t_start,
                                     eta_s=float(sum(durations[number:])))
            self._step_marks.append((now, number))
            if isinstance(step, CreepStep):
                self._creep(acq, step)
            else:
                self._speed(acq, step)
        self.record.loading_window_s = (t_start, acq.clock.now())
        now = acq.clock.now()
        acq.fanout.publish_event("method_progress", now, run_id=self.run_id, method=plan.method,
                                 step=len(plan.steps), steps=len(plan.steps), step_name="done", elapsed_s=now - t_start,
                                 eta_s=0.0)

    def _set_velocity(self, acq: AcquisitionLoop, velocity_deg_per_s: float) -> float:
        """Command the input's velocity; the time (s) its ramp takes at the drive's acceleration."""
        drive = self.bench.input_drive
        assert drive is not None
        acq.station.drive_command(drive.set_velocity, velocity_deg_per_s)
        accel = float(getattr(drive, "acceleration_deg_per_s2", None) or self.method_plan.acceleration_deg_per_s2)
        ramp_s = abs(velocity_deg_per_s - self._velocity_deg_per_s) / accel
        self._velocity_deg_per_s = velocity_deg_per_s
        return ramp_s

    def _speed(self, acq: AcquisitionLoop, step: SpeedStep) -> None:
        """The step's load, then its speed held for its duration: at speed, until the input has turned as far as
        the duration at the speed takes (the angle pairs say; a real-time simulator that stalled has run less than
        the clock), at most twice the duration + TURN_TIMEOUT_S."""
        if step.load_torque_nm != self._setpoint_nm:
            self._run_segment(acq, Segment(step.load_torque_nm, self.method_plan.load_slope_nm_per_s, 0.0, -1))
        ramp_s = self._set_velocity(acq, step.velocity_deg_per_s)
        acq.wait(ramp_s, abort_event=self.abort_event)
        if step.velocity_deg_per_s == 0.0:
            acq.wait(step.duration_s, abort_event=self.abort_event)
            return
        start = acq.station.latest_input_angle_arcsec()
        turn = abs(step.velocity_deg_per_s) * step.duration_s * 3600.0

        def turned() -> bool:
            now = acq.station.latest_input_angle_arcsec()
            return start is not None and now is not None and abs(now - start) >= turn

        acq.wait(step.duration_s, abort_event=self.abort_event)
        if not turned():
            acq.wait(step.duration_s + TURN_TIMEOUT_S, abort_event=self.abort_event, until=turned)
        self._check_following(acq, step.velocity_deg_per_s)

    def _check_following(self, acq: AcquisitionLoop, target_deg_per_s: float) -> None:
        """At the end of a step at speed: the input's measured speed within SPEED_TOLERANCE of its target (a drive
        that does not follow trips ``setpoint_not_followed``, naming the speeds)."""
        drive = self.bench.input_drive
        assert drive is not None
        status: InputDriveStatus = acq.station.drive_command(drive.status)
        window = SPEED_TOLERANCE * abs(target_deg_per_s) + float(getattr(drive, "velocity_window_deg_per_s", 1.0))
        if abs(status.velocity_deg_per_s - target_deg_per_s) > window:
            raise acq.trip_not_followed(f"the input drive turns at {status.velocity_deg_per_s:.1f} deg/s, commanded "
                                        f"{target_deg_per_s:.1f} deg/s")

    def _creep(self, acq: AcquisitionLoop, step: CreepStep) -> None:
        """Creep until the input has turned ``step.turn_deg`` from where it stuck (a breakaway), then stop."""
        start = acq.station.latest_input_angle_arcsec()
        if start is None:
            raise ProcedureError("no reading of the input angle before the creep")
        turn = step.turn_deg * 3600.0

        def moved() -> bool:
            now = acq.station.latest_input_angle_arcsec()
            return now is not None and abs(now - start) >= turn

        self._set_velocity(acq, step.creep_deg_per_s)
        if not acq.wait(step.timeout_s, abort_event=self.abort_event, until=moved):
            self.record.notes.append(f"{step.phase}: the input did not break away within {step.timeout_s:g} s")
        ramp_s = self._set_velocity(acq, 0.0)
        acq.wait(ramp_s, abort_event=self.abort_event)

    # -- every exit: the input to rest first ---------------------------------------------------------------------
    def _safe_stop(self, acq: AcquisitionLoop) -> None:
        with self._lock:
            if self.record.loader_final is not None:
                return
        self._stop_input(acq)
        super()._safe_stop(acq)

    def _stop_input(self, acq: AcquisitionLoop) -> None:
        """The input drive brought to rest and disabled (``Bench.stop_input_drive``, under the drive's lock), then
        waited for (at most its deceleration time + STOP_WAIT_S); a lost input drive is left to its watchdog."""
        drive = self.bench.input_drive
        if drive is None or self._input_stopped:
            return
        self._input_stopped = True
        trip = acq.trip
        failing = acq.station.link_failing()
        if (trip is not None and trip.interlock == "lost_instrument" and "input_drive" in trip.reason) or failing:
            self.record.notes.append(f"input drive lost{f' ({failing})' if failing else ''}: no stop commanded "
                                     "(its own watchdog stops it)")
            return
        with acq.station.drive_lock:
            self.bench.stop_input_drive()
        accel = float(getattr(drive, "acceleration_deg_per_s2", None) or self.method_plan.acceleration_deg_per_s2)
        bound = abs(self._velocity_deg_per_s) / accel + STOP_WAIT_S

        def at_rest() -> bool:
            status = acq.station.poll_drive()
            return status is not None and status.state not in POWERED_STATES

        rested = acq.wait(bound, check_trips=False, until=at_rest)
        self._velocity_deg_per_s = 0.0
        status = acq.station.last_status
        self.record.notes.append(f"input drive stopped: {status.state if status is not None else 'no status'}"
                                 f"{'' if rested else f' (still powered after {bound:.1f} s)'}")

    # -- the record -----------------------------------------------------------------------------------------------
    def _evaluate_without_gaps(self) -> dict[str, Any] | None:
        """The whole record is the method's (no loops to leave out): evaluated as it is."""
        assert self.evaluate is not None
        return self.evaluate(self.record.samples)

    def _tag_loops(self) -> None:
        """``step_index``: the plan's step being run at each sample (−1 before the first and after the last)."""
        s = self.record.samples
        column = np.full(len(s), -1.0)
        if self._step_marks and len(s):
            times = np.array([m[0] for m in self._step_marks])
            idx = np.searchsorted(times, s.time_s, side="right") - 1
            inside = idx >= 0
            if self.record.loading_window_s is not None:
                inside &= s.time_s <= self.record.loading_window_s[1]
            column[inside] = np.array([m[1] for m in self._step_marks], dtype=float)[idx[inside]]
        s.extra[STEP_COLUMN] = column


def run_method(bench: Bench, plan: MethodPlan, **kwargs: Any) -> MethodRun:
    """Start a :class:`MethodRun` in a thread and return it (``.join()`` for the record)."""
    run = MethodRun(bench, plan, **kwargs)
    run.start()
    return run


__all__ = ["STEP_COLUMN", "MethodRun", "loader_segments", "method_limits", "run_method"]

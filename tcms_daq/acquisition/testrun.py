"""The stiffness test procedure as an explicit state machine.

    idle → preparing (enable drive, tare) → loading (ramp the profile's torque setpoints) → evaluating
         → completed | aborted | failed

- **aborted**: an interlock tripped (torque/angle/rate limit, stale data, drive fault, lost instrument) or an
  abort was requested; ``reason`` says which.
- **failed**: anything else went wrong (the loader never reached a setpoint, the data cannot be evaluated, a
  bug); ``reason`` carries the message.

On every exit path, before the final state is entered, the loader is ramped to zero torque and disabled while
acquisition keeps recording; the samples acquired up to the end are kept in the :class:`RunRecord`.

Setpoints: each profile segment is commanded as a profile-torque target with its slope (the drive ramps at
that slope, CiA 402 mode 4); the procedure waits for the ramp, checks that the measured torque reached the
target within a tolerance, and dwells. Time is the bench clock, so on the simulated clock a run takes no real
time.
"""

from __future__ import annotations

import math
import threading
import time
import uuid
from collections.abc import Callable, Iterable, Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from tcms_daq.acquisition.bench import Bench
from tcms_daq.acquisition.fanout import Message
from tcms_daq.acquisition.interlocks import InterlockLimits, Trip
from tcms_daq.acquisition.loop import AbortRequested, AcquisitionLoop, InterlockTripped
from tcms_daq.acquisition.progress import RunProgress
from tcms_daq.acquisition.record import (
    ABORTED,
    COMPLETED,
    EVALUATING,
    FAILED,
    LOADING,
    PREPARING,
    TRANSITIONS,
    RunRecord,
    SampleBuffer,
    StateChange,
    empty_samples,
)
from tcms_daq.analysis.gaps import ANGLE_DATUM_COLUMN, TORQUE_INTERVAL_COLUMN, GapLimits, exclude_gapped_loops
from tcms_daq.analysis.notices import prepend_warnings
from tcms_daq.drivers.base import DeviceFault, InstrumentError, LoaderStatus, Positioner
from tcms_daq.errors import TcmsError
from tcms_daq.procedure.plan import Move, Plan
from tcms_daq.procedure.profiles import OUTSIDE_LOOPS, Profile, Segment
from tcms_daq.runstate import RunState
from tcms_daq.samples import Samples


def _nm(torque_nm: float | None) -> str:
    """A torque reading for a message: '399.9 N·m', or 'no reading'."""
    return "no reading" if torque_nm is None else f"{torque_nm:.1f} N·m"


class ProcedureError(TcmsError):
    """The procedure cannot go on (not an interlock): the run ends ``failed``."""


class ProfileRejected(TcmsError):
    """The profile violates a limit; raised before anything is commanded."""


@dataclass(frozen=True)
class ProcedureOptions:
    """Timing and tolerances (clock seconds, N·m).

    settle_s: wait after connecting and after enabling (readings flowing, watchdog armed);
    tolerance_nm: how close the measured torque must come to each setpoint (None: 2 % of the peak, ≥ 1 N·m);
    settle_timeout_s: extra time allowed to reach a setpoint after its ramp;
    ramp_down_slope_nm_per_s: the least slope of the ramp to zero on exit (None: the profile's steepest slope);
    ramp_down_timeout_s: extra time allowed for the ramp to zero before disabling anyway;
    max_stop_s: every exit disables the loader within this time, whatever the profile: the ramp from the
    *measured* torque is steepened so that it takes at most RAMP_SHARE_OF_STOP of it;
    kept_columns: the sample columns the run record keeps in memory (None: every column; the service keeps the
    canonical three, since its store records the channels as they arrive; the torque interval and the angle datum
    are kept for the gap check whatever this says);
    gaps: what a gap in the data is and how many loops must be left without one (``tcms_daq.analysis.gaps``).
    """

    settle_s: float = 0.2
    tolerance_nm: float | None = None
    settle_timeout_s: float = 2.0
    ramp_down_slope_nm_per_s: float | None = None
    ramp_down_timeout_s: float = 3.0
    max_stop_s: float = 5.0
    kept_columns: tuple[str, ...] | None = None
    gaps: GapLimits = GapLimits()

    def __post_init__(self) -> None:
        if not (math.isfinite(self.max_stop_s) and self.max_stop_s > 0):
            raise ValueError(f"max_stop_s must be a positive number of seconds, got {self.max_stop_s}")


RAMP_SHARE_OF_STOP = 0.6  # of max_stop_s for the ramp to zero; the rest for reaching zero and disabling


def stop_ramp(measured_torque_nm: float, least_slope_nm_per_s: float, max_stop_s: float) -> tuple[float, float]:
    """(slope N·m/s, duration s) of the ramp to zero from the measured torque: at least ``least_slope``, and
    steep enough to take no more than RAMP_SHARE_OF_STOP × ``max_stop_s``."""
    torque = abs(measured_torque_nm) if math.isfinite(measured_torque_nm) else 0.0
    slope = max(least_slope_nm_per_s, torque / (RAMP_SHARE_OF_STOP * max_stop_s), 1e-9)
    return slope, torque / slope


#: what a run works through: a profile, a plan of stages (positions, rates), or bare segments (tests, tools)
RunProfile = Profile | Plan | Sequence[Segment]


def as_segments(profile: RunProfile) -> list[Segment]:
    """The torque segments of a profile, of every stage of a plan, or the segments themselves."""
    if isinstance(profile, Profile):
        out = list(profile.segments)
    elif isinstance(profile, Plan):
        out = profile.segments
    else:
        out = list(profile)
    if not out:
        raise ProfileRejected("profile has no segments")
    return out


def default_limits(bench: Bench, profile: RunProfile, reducer_torque_limit_nm: float | None = None,
                   **overrides: Any) -> InterlockLimits:
    """Interlock limits for a run: bench and reducer torque, a rate limit of twice the steepest profile slope
    (+5 % of the peak per second for sensor noise); the bench config's ``[interlocks]`` table, then
    ``overrides``, replace any field."""
    segments = as_segments(profile)
    peak = max(abs(s.target_nm) for s in segments)
    slope = max(s.slope_nm_per_s for s in segments)
    values: dict[str, Any] = {
        "bench_torque_limit_nm": bench.max_torque_nm if math.isfinite(bench.max_torque_nm) else None,
        "reducer_torque_limit_nm": reducer_torque_limit_nm,
        "torque_rate_limit_nm_per_s": 2.0 * slope + 0.05 * peak,
    }
    for table in (bench.interlocks.replacements(), overrides):
        values.update({k: v for k, v in table.items() if k in InterlockLimits.__dataclass_fields__})
    return InterlockLimits(**values)


def validate_profile(segments: Sequence[Segment], limits: InterlockLimits) -> None:
    """ProfileRejected (one line) when a setpoint or slope is not a number or a slope exceeds the rate limit.
    The test torque is not checked here: ``tcms_daq.procedure.plan.plan_from_request`` holds a request to the
    bench and reducer limits (once), the loader's drive refuses a setpoint beyond its own limit (the last guard),
    and the torque interlock watches the measured torque."""
    for i, seg in enumerate(segments):
        if not (math.isfinite(seg.target_nm) and math.isfinite(seg.slope_nm_per_s)) or seg.slope_nm_per_s <= 0:
            raise ProfileRejected(f"profile segment {i}: invalid target {seg.target_nm} N·m / slope "
                                  f"{seg.slope_nm_per_s} N·m/s")
        rate = limits.torque_rate_limit_nm_per_s
        if rate is not None and seg.slope_nm_per_s > rate:
            raise ProfileRejected(f"profile slope {seg.slope_nm_per_s:g} N·m/s exceeds the rate limit {rate:g} N·m/s")


Evaluator = Callable[[Samples], dict[str, Any] | None]


def analysis_evaluator(rated_torque_nm: float, **options: Any) -> Evaluator:
    """Evaluate with ``tcms_daq.analysis.evaluate`` (rigidity, lost motion, backlash …)."""

    def evaluate(samples: Samples) -> dict[str, Any]:
        from tcms_daq.analysis import evaluate as analysis_evaluate

        return analysis_evaluate(samples.time_s, samples.torque_nm, samples.angle_arcsec,
                                 rated_torque_nm=rated_torque_nm, **options).to_dict()

    return evaluate


class TestRun:
    """One test on a bench, run by :meth:`run` (blocking) or :meth:`start` (a thread).

    subscribers: callables receiving every :class:`DataMessage` and :class:`EventMessage` (``state`` changes,
    ``interlock`` trips) on their own thread from a lossy bounded queue of ``subscriber_queue`` messages (events
    are never dropped), so they cannot block acquisition. A caller that needs every batch subscribes losslessly
    on ``acquisition.fanout`` itself (``subscribe(name, maxsize=None)``), as the run's own recorder does.
    acquisition: a running :class:`AcquisitionLoop` to use (e.g. the service's live one); default: its own.
    abort_event: set it (or call :meth:`abort`) to end the run ``aborted``.
    """

    __test__ = False  # not a pytest test class

    def __init__(self, bench: Bench, profile: RunProfile, *, limits: InterlockLimits | None = None,
                 reducer_torque_limit_nm: float | None = None, evaluate: Evaluator | None = None,
                 options: ProcedureOptions | None = None, subscribers: Iterable[Callable[[Message], Any]] = (),
                 subscriber_queue: int = 256, acquisition: AcquisitionLoop | None = None,
                 abort_event: threading.Event | None = None, run_id: str | None = None,
                 profile_info: dict[str, Any] | None = None):
        self.bench = bench
        # a Plan (several positions or rates: tcms_daq.procedure.plan) runs its steps in order, moves included
        self.plan: Plan | None = profile if isinstance(profile, Plan) else None
        self.segments = as_segments(profile)
        self.limits = limits or default_limits(bench, self.segments, reducer_torque_limit_nm)
        validate_profile(self.segments, self.limits)
        self.evaluate = evaluate
        self.options = options or ProcedureOptions()
        self.subscribers = list(subscribers)
        self.subscriber_queue = subscriber_queue
        self._acq = acquisition
        self.abort_event = abort_event or threading.Event()
        peak = max(abs(s.target_nm) for s in self.segments)
        self.tolerance_nm = (self.options.tolerance_nm if self.options.tolerance_nm is not None
                             else max(0.02 * peak, 1.0))
        info = profile.to_dict() if isinstance(profile, Profile | Plan) else {}
        if self.plan is not None:
            info = {**self.plan.first.to_dict(), **info}
        self.record = RunRecord(run_id or uuid.uuid4().hex[:12], bench_name=bench.name,
                                profile={**info, **(profile_info or {}),
                                         "segments": [asdict(s) for s in self.segments]},
                                limits=self.limits.to_dict())
        # (clock time a step was commanded, its loop index, its stage index)
        self._marks: list[tuple[float, int, int]] = []
        self._thread: threading.Thread | None = None
        self._done = threading.Event()
        self._setpoint_nm = 0.0
        self._start_position_deg: float | None = None  # the output's position at the start (deg), if reported
        self._lock = threading.Lock()

    # -- public API -----------------------------------------------------------------------------------
    @property
    def state(self) -> RunState:
        return self.record.state

    @property
    def run_id(self) -> str:
        return self.record.run_id

    @property
    def acquisition(self) -> AcquisitionLoop | None:
        return self._acq

    def start(self) -> TestRun:
        """Run in a daemon thread; returns at once."""
        self._thread = threading.Thread(target=self.run, name=f"tcms-run-{self.run_id}", daemon=True)
        self._thread.start()
        return self

    def join(self, timeout: float | None = None) -> RunRecord:
        self._done.wait(timeout)
        return self.record

    def abort(self, reason: str = "aborted by operator") -> None:
        """Request an abort: the run ramps down, disables the loader and ends ``aborted`` with ``reason``."""
        self.abort_event.reason = reason  # type: ignore[attr-defined]
        self.abort_event.set()

    def run(self) -> RunRecord:
        """Run the whole procedure in the calling thread; never raises for a test outcome."""
        acq = self._acq
        own_acq = acq is None
        own_connect = False
        subs = []
        buffer: SampleBuffer | None = None
        try:
            self._transition(PREPARING)
            if not self.bench.connected:
                self.bench.connect()
                own_connect = True
                safe_start = self.bench.safe_start  # what connecting found on the loader and did about it
                if safe_start is not None and (safe_start.actions or safe_start.found_error_code
                                               or not safe_start.safe):
                    self.record.notes.append(safe_start.message)
                if safe_start is not None and not safe_start.safe:
                    raise TcmsError(safe_start.message)
            if acq is None:
                acq = AcquisitionLoop(self.bench, self.limits)
                self._acq = acq
            acq.drive_fault_armed = False  # until _prepare has reset a fault an earlier run left
            acq.set_limits(self.limits)
            self._station(acq, True)
            kept = self.options.kept_columns
            # every batch, copied in by the acquisition thread: the run's samples (with what the gap check needs)
            buffer = SampleBuffer(None if kept is None else (*kept, TORQUE_INTERVAL_COLUMN, ANGLE_DATUM_COLUMN))
            acq.fanout.add_sink(buffer.append)
            subs = [acq.fanout.subscribe_callback(cb, maxsize=self.subscriber_queue) for cb in self.subscribers]
            self._publish_state()
            acq.start()
            self._prepare(acq)
            self._load(acq)
            self._safe_stop(acq)
            self._transition(EVALUATING)
            self._collect(buffer)
            if self.evaluate is not None:
                self.record.evaluation = self._evaluate_without_gaps()
            self._transition(COMPLETED)
        except (InterlockTripped, AbortRequested) as exc:
            self._finish_early(acq, buffer, ABORTED, exc)
        except InstrumentError as exc:  # a command failed: treat like the matching interlock
            if acq is None:  # could not even connect
                self._finish_early(acq, buffer, FAILED, exc)
                return self.record
            # commands through the loop tripped already, naming their instrument; this names any other call
            kind = "device_fault" if isinstance(exc, DeviceFault) else "lost_instrument"
            trip = Trip(kind, f"instrument error: {exc}", acq.clock.now())
            acq.raise_trip(trip)
            self._finish_early(acq, buffer, ABORTED, InterlockTripped(acq.trip or trip))
        except Exception as exc:
            self._finish_early(acq, buffer, FAILED, exc)
        finally:
            try:
                if acq is not None:
                    self._safe_stop(acq)
                    if own_acq:
                        acq.stop()
                    self._station(acq, False)
                    if buffer is not None:
                        acq.fanout.remove_sink(buffer.append)
                    self._collect(buffer)
                    self.record.acquisition = {
                        "channels": acq.channel_stats(),
                        "subscribers": {s.name: {"dropped": s.dropped, "delivered": s.delivered} for s in subs},
                        "recorded_samples": len(buffer) if buffer is not None else 0,
                    }
                    for s in subs:
                        s.close()
                    if own_acq:
                        acq.fanout.close()
            finally:
                if own_connect:
                    self.bench.close()
                self.record.finished_wall = time.time()
                self._done.set()
        return self.record

    def _evaluate_without_gaps(self) -> dict[str, Any] | None:
        """The evaluation of the loops that hold no gap (each left-out loop a warning naming the gap); a
        ProcedureError (the run fails) when too few loops are left."""
        assert self.evaluate is not None
        exclusion = exclude_gapped_loops(self.record.evaluated_samples(), self.options.gaps)
        if exclusion.reason is not None:
            raise ProcedureError(exclusion.reason)
        evaluation = self.evaluate(exclusion.samples)
        if exclusion.warnings and isinstance(evaluation, dict):
            prepend_warnings(evaluation, exclusion.warnings)
        return evaluation

    # -- the phases ----------------------------------------------------------------------------------
    def _station(self, acq: AcquisitionLoop, active: bool) -> None:
        """Before anything is recorded (True) and after the safe stop and the last samples (False): whether the
        acquisition serves this run in station mode (a turning test's: ``MethodRun``); the stiffness test's is not."""

    def _load(self, acq: AcquisitionLoop) -> None:
        """The loading phase: the profile's segments (a plan's moves and stages in order), with progress events."""
        self._transition(LOADING)
        t_start = acq.clock.now()
        steps: list[tuple[int, Move | Segment]] = (self.plan.steps() if self.plan is not None
                                                   else [(0, seg) for seg in self.segments])
        progress = RunProgress(self.run_id, self.plan, self.segments, t_start, self._start_position_deg)
        for number, (stage, step) in enumerate(steps):
            progress.publish(acq.fanout, acq.clock.now(), number, stage, step)
            if isinstance(step, Move):
                self._run_move(acq, step, stage)
            else:
                self._run_segment(acq, step, stage)
        self.record.loading_window_s = (t_start, acq.clock.now())
        progress.publish(acq.fanout, acq.clock.now(), len(steps), -1, None)

    def _prepare(self, acq: AcquisitionLoop) -> None:
        opts = self.options
        acq.drive_fault_armed = False  # a fault left by an earlier run is reset here, not tripped on
        acq.disable_pending = False  # this run takes the loader over
        acq.wait(opts.settle_s, abort_event=self.abort_event)
        status = acq.loader_command(self.bench.loader.status)
        self._start_position_deg = status.position_deg
        if status.fault:
            self.record.notes.append(f"loader was in FAULT (0x{status.error_code:04X}) before the test: reset")
            acq.loader_command(self.bench.loader.fault_reset)
        acq.instrument_command("torque", self.bench.torque.tare)
        acq.loader_command(self.bench.loader.enable)
        acq.drive_fault_armed = True
        self._setpoint_nm = 0.0
        acq.wait(opts.settle_s, abort_event=self.abort_event)

    def _run_move(self, acq: AcquisitionLoop, move: Move, stage: int) -> None:
        """Turn the output to the stage's position: only at zero torque (the profile before it ended at zero;
        the loader refuses a move under torque too), then back to profile torque at zero."""
        loader = self.bench.loader
        if not isinstance(loader, Positioner):
            raise ProcedureError(f"{loader.name} cannot turn the output (no profile position mode): a test at "
                                 "several positions needs a loader with move_to")
        measured = acq.latest_torque_nm()
        if measured is None or abs(measured) > self.tolerance_nm:
            raise ProcedureError(f"torque {_nm(measured)} before the move to {move.position_deg:g}°: no move under "
                                 f"torque (window ±{self.tolerance_nm:g} N·m)")
        self._marks.append((acq.clock.now(), OUTSIDE_LOOPS, stage))
        before: LoaderStatus = acq.loader_command(loader.status)
        start_deg = before.position_deg if before.position_deg is not None else move.position_deg
        travel_s = abs(move.position_deg - start_deg) / move.velocity_deg_per_s
        acq.loader_command(loader.move_to, move.position_deg, move.velocity_deg_per_s)
        self.record.notes.append(f"stage {stage + 1}: output moved from {start_deg:.3f}° to {move.position_deg:g}°")

        def arrived() -> bool:
            st: LoaderStatus = acq.loader_command(loader.status)
            return (not st.moving and st.position_deg is not None
                    and abs(st.position_deg - move.position_deg) <= 0.05)

        acq.wait(travel_s, abort_event=self.abort_event)
        if not acq.wait(self.options.settle_timeout_s + 0.1 * travel_s, abort_event=self.abort_event, until=arrived):
            st = acq.loader_command(loader.status)
            at = "an unreported position" if st.position_deg is None else f"{st.position_deg:.3f}°"
            raise acq.trip_not_followed(f"the output did not reach {move.position_deg:g}° (at {at})")
        acq.loader_command(loader.enable)  # profile torque again, target zero
        acq.wait(self.options.settle_s, abort_event=self.abort_event)

    def _run_segment(self, acq: AcquisitionLoop, seg: Segment, stage: int = 0) -> None:
        start_nm = self._setpoint_nm
        self._marks.append((acq.clock.now(), seg.loop_index, stage))
        acq.loader_command(self.bench.loader.set_torque, seg.target_nm, seg.slope_nm_per_s)
        self._setpoint_nm = seg.target_nm
        ramp_s = abs(seg.target_nm - start_nm) / seg.slope_nm_per_s
        acq.wait(ramp_s, abort_event=self.abort_event)

        def near() -> bool:
            tq = acq.latest_torque_nm()
            return tq is not None and abs(tq - seg.target_nm) <= self.tolerance_nm

        if not acq.wait(self.options.settle_timeout_s + 0.1 * ramp_s, abort_event=self.abort_event, until=near):
            raise acq.trip_not_followed(f"did not reach {seg.target_nm:g} N·m within ±{self.tolerance_nm:g} N·m "
                                        f"(measured {_nm(acq.latest_torque_nm())})")
        if seg.dwell_s > 0:
            acq.wait(seg.dwell_s, abort_event=self.abort_event)

    def _safe_stop(self, acq: AcquisitionLoop) -> None:
        """Ramp to zero torque and disable; every step tried even if an earlier one failed. Idempotent.

        While the measured torque is above the torque limit the ramp is not waited for: the loader is
        disabled at once (a drive that does not follow its setpoints is stopped by removing its enable).
        """
        with self._lock:
            if self.record.loader_final is not None:
                return
            loader = self.bench.loader
            slope = self.options.ramp_down_slope_nm_per_s or max(s.slope_nm_per_s for s in self.segments)
            trip = acq.trip
            loader_lost = trip is not None and trip.interlock == "lost_instrument" and "loader" in trip.reason
            if loader_lost:
                # nothing to command the ramp with: the drive's own communication watchdog takes the torque off
                self.record.notes.append("loader lost: no ramp to zero commanded; disable attempted")
            else:
                try:
                    started_s = acq.clock.now()
                    measured = acq.latest_torque_nm()
                    slope, ramp_s = stop_ramp(self._setpoint_nm if measured is None else measured, slope,
                                              self.options.max_stop_s)
                    acq.loader_command(loader.set_torque, 0.0, slope)
                    self._setpoint_nm = 0.0
                    limit_nm = self.limits.torque_limit_nm

                    def over_limit() -> bool:  # a drive out of control: do not wait for the ramp, disable now
                        return abs(acq.latest_torque_nm() or 0.0) > limit_nm

                    if not acq.wait(ramp_s, check_trips=False, until=over_limit):
                        left_s = self.options.max_stop_s - (acq.clock.now() - started_s)
                        acq.wait(max(0.0, min(self.options.ramp_down_timeout_s, left_s)), check_trips=False,
                                 until=lambda: over_limit() or abs(acq.latest_torque_nm() or 0.0) <= self.tolerance_nm)
                except Exception as exc:
                    self.record.notes.append(f"ramp to zero failed: {exc}")
            try:
                acq.loader_command(loader.disable)
            except Exception as exc:
                self.record.notes.append(f"disable failed: {exc}; the loader is disabled when it answers again")
                acq.disable_pending = True
            acq.wait(self.options.settle_s, check_trips=False)
            if loader_lost:
                self.record.loader_final = {"state": "unknown", "error": "loader lost"}
                return
            try:
                status: LoaderStatus = acq.loader_command(loader.status)
                self.record.loader_final = {"state": status.state, "torque_actual_nm": status.torque_actual_nm,
                                            "fault": status.fault, "error_code": status.error_code}
            except Exception as exc:
                self.record.loader_final = {"state": "unknown", "error": str(exc)}

    def _finish_early(self, acq: AcquisitionLoop | None, buffer: SampleBuffer | None, state: RunState,
                      exc: BaseException) -> None:
        if isinstance(exc, InterlockTripped):
            reason = exc.trip.reason
            self.record.trip = exc.trip.to_dict()
        elif isinstance(exc, AbortRequested):
            reason = exc.reason
        else:
            reason = str(exc) or type(exc).__name__
            if not isinstance(exc, TcmsError):
                reason = f"{type(exc).__name__}: {reason}"
        if acq is not None:
            if self.record.loading_window_s is None and self.record.state == LOADING:
                start = next((h.time_s for h in self.record.history if h.state == LOADING), acq.clock.now())
                self.record.loading_window_s = (start, acq.clock.now())
            try:
                self._safe_stop(acq)
            except Exception as stop_exc:  # pragma: no cover - _safe_stop records its own failures
                self.record.notes.append(f"safe stop: {stop_exc}")
            self._collect(buffer)
        self._transition(state, reason)

    def _collect(self, buffer: SampleBuffer | None) -> None:
        if buffer is None or not len(buffer):
            return
        self.record.samples = empty_samples()  # let the buffer join its chunks in place (no second copy)
        self.record.samples = buffer.to_samples()
        self._tag_loops()

    def _tag_loops(self) -> None:
        """``loop_index`` column: the loop index of the segment being run at each sample (−1 outside); a plan's
        run also gets ``stage_index``: the stage (position or rate, 0-based) of each sample (−1 outside)."""
        s = self.record.samples
        loop = np.full(len(s), float(OUTSIDE_LOOPS))
        stage = np.full(len(s), -1.0)
        if self._marks and len(s):
            times = np.array([m[0] for m in self._marks])
            idx = np.searchsorted(times, s.time_s, side="right") - 1
            inside = idx >= 0
            if self.record.loading_window_s is not None:
                inside &= s.time_s <= self.record.loading_window_s[1]
            loop[inside] = np.array([m[1] for m in self._marks], dtype=float)[idx[inside]]
            stage[inside] = np.array([m[2] for m in self._marks], dtype=float)[idx[inside]]
        s.extra["loop_index"] = loop
        if self.plan is not None:
            s.extra["stage_index"] = stage

    # -- state machine -------------------------------------------------------------------------------
    def _transition(self, state: RunState, reason: str | None = None) -> None:
        current = self.record.state
        if state not in TRANSITIONS[current]:
            raise ProcedureError(f"invalid state transition {current} → {state}")
        now = self._acq.clock.now() if self._acq is not None else self.bench.clock.now()
        self.record.history.append(StateChange(state, now, time.time(), reason))
        self.record.state = state
        if reason is not None:
            self.record.reason = reason
        self._publish_state()

    def _publish_state(self) -> None:
        if self._acq is None:
            return
        last = self.record.history[-1] if self.record.history else None
        self._acq.fanout.publish_event("state", last.time_s if last else self._acq.clock.now(),
                                       run_id=self.run_id, state=self.record.state, reason=self.record.reason)


def run_test(bench: Bench, profile: Any, **kwargs: Any) -> TestRun:
    """Start a :class:`TestRun` in a thread and return it (``.join()`` for the record, ``.abort()`` to stop)."""
    return TestRun(bench, profile, **kwargs).start()


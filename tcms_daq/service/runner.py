"""The one place where the service touches the bench, the procedure and the evaluation.

The service needs a small surface (:class:`Runner`): open the bench and stream every acquired batch to a sink
(the live hub), validate a test request into a plan, execute a plan in the calling (worker) thread while
recording its batches, abort, report the bench state, and get/replace the compensator. :class:`BenchRunner`
implements it over the acquisition layer; swapping the procedure implementation is a change to this file only.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from tcms_daq.config.models import BenchConfig, CompensationChecks, ReducerSpec
from tcms_daq.errors import TcmsError
from tcms_daq.procedure.methods import METHODS, missing_for
from tcms_daq.procedure.plan import MethodTestPlan, PlanRequest, TestPlan
from tcms_daq.protocols.cia402 import POWERED_STATES as POWERED
from tcms_daq.samples import INPUT_ANGLE_COLUMN, INPUT_TORQUE_COLUMN
from tcms_daq.service.schemas import TestRequest

if TYPE_CHECKING:  # the acquisition is imported when the bench is composed, not when the service starts
    from tcms_daq.acquisition.bench import Bench, Compensation

Columns = Mapping[str, np.ndarray]
_PLAN_FIELDS = set(PlanRequest.model_fields)  # what of a TestRequest the plan is made of (the rest documents the test)
BatchSink = Callable[[Columns], None]

# Channels recorded for every run (the canonical columns plus the raw encoder angle).
RUN_CHANNELS: tuple[str, ...] = ("time_s", "torque_nm", "angle_arcsec", "encoder_arcsec")
# … and for a turning test: the input angle and (when the bench has its channel) the input torque
METHOD_CHANNELS: tuple[str, ...] = (*RUN_CHANNELS, INPUT_ANGLE_COLUMN, INPUT_TORQUE_COLUMN)


class RequestRejected(TcmsError):
    """A test request the bench cannot run (unknown reducer, torque above a limit …): HTTP 422."""


@dataclass
class AcceptedTest:
    """A validated request: the profile summary stored with the run, and the runner's own plan object (the
    bench runner's: a :class:`tcms_daq.procedure.plan.TestPlan` or ``MethodTestPlan``); ``channels`` the run's
    recorded channels when they are not the runner's."""

    request: TestRequest
    profile_summary: dict[str, Any]
    payload: Any = None
    channels: tuple[str, ...] | None = None


@dataclass
class RunOutcome:
    status: str  # completed | aborted | failed
    error: str | None = None
    results: dict[str, Any] | None = None


class Runner(Protocol):
    channels: tuple[str, ...]

    def open(self, live_sink: BatchSink) -> None: ...

    def close(self) -> None: ...

    def status(self) -> dict[str, Any]: ...

    def config_snapshot(self) -> dict[str, Any]: ...

    def compensator_toml(self) -> str: ...

    def set_compensator_toml(self, text: str) -> None: ...

    def compensation_checks(self) -> CompensationChecks: ...

    def plan(self, request: TestRequest) -> AcceptedTest: ...

    def execute(
        self,
        plan: AcceptedTest,
        *,
        run_id: str,
        record: BatchSink,
        on_phase: Callable[..., None],
        abort: threading.Event,
    ) -> RunOutcome: ...


def _columns(samples: Any, extra: tuple[str, ...] = ()) -> dict[str, np.ndarray]:
    out = {
        "time_s": samples.time_s,
        "torque_nm": samples.torque_nm,
        "angle_arcsec": samples.angle_arcsec,
        "encoder_arcsec": samples.extra.get("encoder_arcsec", samples.angle_arcsec),
    }
    for name in extra:
        column = samples.extra.get(name)
        out[name] = column if column is not None else np.full(len(samples.time_s), np.nan)
    return out


IDLE_STEP_PERIODS = 2  # the idle pump's step in loop steps: 2 × 20 ms of real time = one live frame (25 /s)
SECOND_AXIS = ("input_drive", "input_torque", "input_angle")
TE_LIVE_PERIOD_S = 0.5  # clock seconds between two te_live events
TE_LIVE_POINTS = 200  # at most this many points per te_live event


class TeLiveFeed:
    """The transmission-error test's live messages (``te_live`` on ``WS /ws/events``, the results contract of
    docs/transmission.md): the raw TE θ_out − θ_in/i (compensated output angle) against the output angle, both from
    their values where the present direction began, about every TE_LIVE_PERIOD_S of the clock, decimated."""

    def __init__(self, ratio: float, emit: Callable[..., None]):
        self.ratio = float(ratio)
        self.emit = emit
        self._origin: tuple[float, float] | None = None  # (output angle ″, TE ″) where the direction began
        self._direction: str | None = None
        self._t: list[np.ndarray] = []
        self._a: list[np.ndarray] = []
        self._te: list[np.ndarray] = []
        self._last_s: float | None = None

    def add(self, samples: Any) -> None:
        inputs = samples.extra.get(INPUT_ANGLE_COLUMN)
        if inputs is None or len(inputs) < 2:
            return
        out = np.asarray(samples.angle_arcsec, dtype=float)
        te = out - np.asarray(inputs, dtype=float) / self.ratio
        step = float(inputs[-1] - inputs[0])
        direction = None if step == 0 else ("forward" if step > 0 else "reverse")
        if direction is None:
            return
        if direction != self._direction:
            self._flush()
            self._direction, self._origin = direction, (float(out[0]), float(te[0]))
        assert self._origin is not None
        self._t.append(np.asarray(samples.time_s, dtype=float))
        self._a.append((out - self._origin[0]) / 3600.0)
        self._te.append(te - self._origin[1])
        now = float(samples.time_s[-1])
        if self._last_s is None:
            self._last_s = now
        if now - self._last_s >= TE_LIVE_PERIOD_S:
            self._flush()
            self._last_s = now

    def _flush(self) -> None:
        if not self._a or self._direction is None:
            return
        angle, te = np.concatenate(self._a), np.concatenate(self._te)
        idx = np.unique(np.linspace(0, angle.size - 1, min(angle.size, TE_LIVE_POINTS)).astype(int))
        self.emit("te_live", direction=self._direction, output_angle_deg=[round(float(v), 5) for v in angle[idx]],
                  te_arcsec=[round(float(v), 3) for v in te[idx]])
        self._t, self._a, self._te = [], [], []


def method_evaluator(config: BenchConfig, config_path: Path, plan: MethodTestPlan) -> Callable[[Any], dict[str, Any]]:
    """The evaluation of a turning test's samples with the config's ``[uncertainty.station]``."""
    from tcms_daq.procedure.method_evaluation import evaluate_method

    chain, source = config.uncertainty.station, config_path.name

    def run(samples: Any) -> dict[str, Any]:
        return evaluate_method(samples, plan.method, plan.reducer, plan.method_plan.parameters, chain=chain,
                               source=source)

    return run


class BenchRunner:
    """The service's bench: an :class:`~tcms_daq.acquisition.AcquisitionLoop` that runs for the life of the
    service (feeding the live hub while idle, too) and :class:`~tcms_daq.acquisition.TestRun` state machines
    executed on that same loop.

    On a simulated clock, time only moves when someone waits on the loop: an idle pump thread waits in short
    steps between tests, and a test holds ``_clock_lock`` for its whole run so exactly one thread drives the
    clock. ``sim_speed`` sets simulated seconds per real second; the idle pump lets one step of ``idle_step_s``
    pass at a time (default ``IDLE_STEP_PERIODS`` loop steps: on a paced clock about 40 ms of real time, the live
    view's frame period, so an idle service wakes 25 times a real second whatever the speed). A test that waits for
    the clock gets it at the pump's next step (``_test_waiting``): a lock is not fair, and the pump, taking it
    again as soon as it let it go, kept a test waiting for seconds of real time on a loaded machine (hundreds of
    simulated seconds at 40×).
    """

    channels = RUN_CHANNELS

    def __init__(self, config: BenchConfig, config_path: Path, bench: Bench, reducers: Mapping[str, ReducerSpec],
                 sim_speed: float = 1.0, idle_step_s: float | None = None):
        self.config = config
        self.config_path = config_path
        self.bench = bench
        self.reducers = dict(reducers)
        self.sim_speed = sim_speed
        self.idle_step_s = idle_step_s
        self.acq: Any = None
        self._live: BatchSink | None = None
        self._clock_lock = threading.Lock()
        self._test_waiting = threading.Event()  # a test waits for the clock: the idle pump steps aside
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._live_sub: Any = None

    @classmethod
    def from_config(cls, config_path: Path | str | None = None, sim_speed: float = 1.0,
                    overrides: list[str] | tuple[str, ...] = (), *,
                    physics_factory: Callable[[BenchConfig], object] | None = None,
                    compensator: Compensation | None = None) -> BenchRunner:
        """Compose the bench of a config file (default: the packaged ``bench-sim.toml``; ``overrides`` as
        ``tcms serve --set``); ``physics_factory`` and ``compensator`` go to
        :func:`~tcms_daq.acquisition.compose_bench`."""
        from tcms_daq.acquisition import compose_bench
        from tcms_daq.config import load_bench_config, load_reducers_for
        from tcms_daq.config.loader import default_bench_config_path

        config = load_bench_config(config_path, overrides)
        path = Path(config.source_path or default_bench_config_path())
        reducers = load_reducers_for(config)
        bench = compose_bench(config, config_dir=path.parent, speed=sim_speed, physics_factory=physics_factory,
                              compensator=compensator)
        return cls(config, path, bench, reducers, sim_speed=sim_speed)

    # -- life cycle ------------------------------------------------------------------------------------------
    def open(self, live_sink: BatchSink) -> None:
        from tcms_daq.acquisition import AcquisitionLoop

        self._live = live_sink
        if not self.bench.connected:  # tcms serve connects first, to fail with one line before it starts
            self.bench.connect()
        self.acq = AcquisitionLoop(self.bench)
        report = getattr(self.bench, "safe_start", None)
        if report is not None and not report.safe:
            self.acq.disable_pending = True  # the status poll disables the loader as soon as it answers
        self._live_sub = self.acq.fanout.subscribe_callback(self._to_live, name="live", maxsize=64)
        self.acq.start()
        if self.acq.clock.stepped:
            self._resync_clock()  # the start-up's real time is not made up in an unpaced burst
            self._spawn(self._pump_idle_clock, "tcms-idle-clock")

    def _spawn(self, target: Callable[[], None], name: str) -> None:
        thread = threading.Thread(target=target, name=name, daemon=True)
        thread.start()
        self._threads.append(thread)

    def close(self) -> None:
        self._stop.set()
        if self._live_sub is not None:
            self._live_sub.close()
        for thread in self._threads:
            thread.join(5.0)
        self._threads.clear()
        if self.acq is not None:
            self.acq.close()
        self.bench.close()

    def _resync_clock(self) -> None:
        """Hand the simulated clock over without a catch-up: the time it stood still (a test's evaluation, which
        holds the clock; the start-up) is dropped, so the idle pump goes on paced instead of stepping unpaced
        until the simulation has made it up, and a test starts on a clock that keeps pace."""
        resync = getattr(self.bench.clock, "resync", None)
        if resync is not None:
            resync()

    def _to_live(self, msg: Any) -> None:
        if msg.kind == "data" and self._live is not None:
            self._live(_columns(msg.samples))

    def _pump_idle_clock(self) -> None:
        """Between tests, let simulated time pass (paced by the clock's speed) so the live view keeps moving."""
        while not self._stop.is_set():
            if self._test_waiting.is_set():
                time.sleep(0.005)
                continue
            if not self._clock_lock.acquire(timeout=0.1):
                continue
            try:
                idle_step_s = self.idle_step_s or IDLE_STEP_PERIODS * self.acq.period_s
                self.acq.wait(idle_step_s, step_s=idle_step_s, check_trips=False)
            except TcmsError:
                pass
            finally:
                self._clock_lock.release()

    # -- state -----------------------------------------------------------------------------------------------
    def status(self) -> dict[str, Any]:
        loader = None
        trip = None
        stats = self.acq.channel_stats() if self.acq is not None else {}
        if self.acq is not None:
            st = self.acq.last_status
            if st is not None:
                link = stats.get("loader", {})
                loader = {"state": st.state, "torque_actual_nm": st.torque_actual_nm, "fault": st.fault,
                          "error_code": st.error_code, "position_deg": st.position_deg, "moving": st.moving,
                          "age_s": link.get("age_s"), "live": link.get("link") == "up"}
            trip = self.acq.trip.to_dict() if self.acq.trip is not None else None
        input_drive = None
        if self.acq is not None and self.acq.station.last_status is not None:
            st2 = self.acq.station.last_status
            link = stats.get("input_drive", {})
            input_drive = {"state": st2.state, "velocity_deg_per_s": st2.velocity_deg_per_s, "fault": st2.fault,
                           "error_code": st2.error_code, "position_deg": st2.position_deg,
                           "age_s": link.get("age_s"), "live": link.get("link") == "up"}
        kinds = ("angle", "torque", "loader", *(k for k in SECOND_AXIS if getattr(self.bench, k, None) is not None))
        instruments = {
            kind: {**dict(self.bench.description.get(kind, {})),
                   **stats.get(kind, {}), **({"status": loader} if kind == "loader" else {}),
                   **({"status": input_drive} if kind == "input_drive" else {})}
            for kind in kinds
        }
        return {
            "name": self.bench.name,
            "config": str(self.config_path),
            "max_torque_nm": self.bench.max_torque_nm,
            "clock": "simulated" if self.bench.clock.stepped else "monotonic",
            "sim_speed": self.sim_speed if self.bench.clock.stepped else None,
            "monotonic_at_clock_zero_s": self._monotonic_at_clock_zero(),
            "connected": bool(self.bench.connected),
            "compensation": self.bench.description.get("compensation"),
            "instruments": instruments,
            "last_interlock": trip,
            "samples_published": self.acq.samples_published if self.acq is not None else 0,
            "reducers": [{"name": r.name, "kind": r.kind, "rated_torque_nm": r.rated_torque_nm,
                          "max_test_torque_nm": min(r.rated_torque_nm, self.bench.max_torque_nm)}
                         for r in self.reducers.values()],
            "test_bounds": self.test_bounds(),
            "acquisition_step": ({"clock_s": self.acq.period_s, "real_s": self.acq.step_real_s}
                                 if self.acq is not None else None),
            "safe_start": self.safe_start(),
            "input_safe_start": (None if (second := getattr(self.bench, "input_safe_start", None)) is None
                                 else second.to_dict()),
            "methods": {m: (None if not (missing := missing_for(m, self.config)) else f"needs {' and '.join(missing)}")
                        for m in METHODS},  # each method, and why this bench cannot run it (None: it can)
            "not_ready": self.not_ready_reason(),
        }

    def safe_start(self) -> dict[str, Any] | None:
        """What the bench's safe start found on the loader and did (``acquisition.bench.SafeStart``)."""
        report = getattr(self.bench, "safe_start", None)
        return report.to_dict() if report is not None else None

    def not_ready_reason(self) -> str | None:
        """Why no test may start now (None: it may): the safe start left the loader unsafe and no fresh status has
        shown it safe since (the status poll disables a loader left enabled as soon as it answers)."""
        from tcms_daq.acquisition.bench import is_safe

        second = getattr(self.bench, "input_safe_start", None)
        if second is not None and not second.safe:
            status = self.acq.station.last_status if self.acq is not None else None
            if status is not None and status.state not in POWERED and not status.fault:
                second.safe = True
                second.message += f"; safe since ({status.state})"
            else:
                return f"the bench is not safe yet: {second.message}"
        report = getattr(self.bench, "safe_start", None)
        if report is None or report.safe:
            return None
        if self.acq is not None:
            status = self.acq.last_status
            link = self.acq.channel_stats()["loader"]
            if status is not None and link["link"] == "up" and is_safe(status.state, status.torque_actual_nm,
                                                                      report.safe_torque_nm):
                report.safe = True
                report.message += f"; safe since ({status.state} at {status.torque_actual_nm:.1f} N·m)"
                return None
        return f"the bench is not safe yet: {report.message}"
    def test_bounds(self) -> dict[str, float]:
        """The bounds ``POST /api/tests`` checks (``check_test_bounds`` and the torque limits), for forms."""
        section = self.config.bench
        return {
            "min_torque_nm": section.min_test_torque_nm,
            "max_torque_nm": self.bench.max_torque_nm,
            "min_rate_nm_per_s": section.min_rate_nm_per_s,
            "max_rate_nm_per_s": section.rate_limit_nm_per_s,
            "min_step_nm": section.min_step_nm,
            "max_test_duration_s": section.max_test_duration_s,
            "max_segments": section.max_segments,
        }

    def _monotonic_at_clock_zero(self) -> float | None:
        """``time.monotonic()`` (system-wide on Linux) at which the sample clock read 0, so a client can turn
        sample time stamps into its own monotonic time: ``t_mono = this + time_s / speed``. Real instruments
        stamp with ``time.monotonic`` itself (0); a paced simulated clock has an offset that holds from one test's end
        to the next's (each test's end re-anchors it: :meth:`_resync_clock`); None when unpaced."""
        return self.bench.clock.monotonic_at_zero_s()

    def config_snapshot(self) -> dict[str, Any]:
        """The configuration a run records (the OPC UA users' password hashes left out: only their names)."""
        snapshot = {"source": str(self.config_path), "sim_speed": self.sim_speed,
                    **self.config.model_dump(mode="json")}
        opcua = snapshot.get("opcua")
        if isinstance(opcua, dict) and isinstance(opcua.get("users"), dict):
            opcua["users"] = sorted(opcua["users"])
        return snapshot

    # -- compensation ----------------------------------------------------------------------------------------
    def compensator_toml(self) -> str:
        to_toml = getattr(self.bench.compensator, "to_toml", None)
        if to_toml is not None:
            return to_toml()
        from tcms_daq.compensation import Compensator

        return Compensator.identity().to_toml()

    def set_compensator_toml(self, text: str) -> None:
        """Replace the compensator (compensator TOML or geometry TOML). RequestRejected when it does not load or
        is not plausible (``tcms_daq.store.compensation.checked_compensator``)."""
        from tcms_daq.store.compensation import CompensationRejected, checked_compensator

        try:
            compensator = checked_compensator(text, checks=self.compensation_checks())
        except CompensationRejected as exc:
            raise RequestRejected(str(exc)) from None
        self.bench.compensator = compensator  # one attribute swap: the next batch uses it
        self.bench.description["compensation"] = "uploaded (PUT /api/compensation)"

    def compensation_checks(self) -> CompensationChecks:
        """The bands an uploaded compensator must keep (the bench config's [compensation_checks])."""
        checks: CompensationChecks = self.config.compensation_checks
        return checks

    # -- tests -----------------------------------------------------------------------------------------------
    def plan(self, request: TestRequest) -> AcceptedTest:
        """The request's plan (``plan_from_request``: the one limit policy); RequestRejected (422) naming what is
        out of bounds, or when positions are asked of a loader that cannot turn the output."""
        from tcms_daq.procedure.plan import PlanRejected, PlanRequest, plan_from_request

        try:
            planned = plan_from_request(PlanRequest.model_validate(
                request.model_dump(include=_PLAN_FIELDS, exclude_none=request.method != "stiffness")),
                self.config, self.reducers)
        except PlanRejected as exc:
            raise RequestRejected(str(exc)) from None
        if isinstance(planned, MethodTestPlan):
            channels = tuple(c for c in METHOD_CHANNELS
                             if c != INPUT_TORQUE_COLUMN or self.bench.input_torque is not None)
            return AcceptedTest(request, planned.summary(), planned, channels)
        if planned.plan.kind == "positions" and not callable(getattr(self.bench.loader, "move_to", None)):
            raise RequestRejected(f"positions: the loader {self.bench.loader.name} cannot turn the output")
        return AcceptedTest(request, planned.summary(), planned)

    def _evaluator(self, plan: TestPlan) -> Callable[[Any], dict[str, Any]]:
        from tcms_daq.procedure.evaluation import evaluate_for_reducer, evaluate_plan

        chain = self.config.chain_uncertainty()
        without = f"type A only (no uncertainty declared in {self.config_path.name})"

        def run(samples: Any) -> dict[str, Any]:
            # TestRun hands over the evaluated loops only (loop_index >= 1: conditioning removed)
            if plan.plan.kind != "single":
                return evaluate_plan(samples, plan.plan, plan.reducer, chain=chain, rule=plan.decision_rule,
                                     no_chain_basis=without)
            return evaluate_for_reducer(samples, plan.reducer, plan.profile.test_torque_nm, chain=chain,
                                        rule=plan.decision_rule, no_chain_basis=without).to_dict()

        return run

    def execute(self, plan: AcceptedTest, *, run_id: str, record: BatchSink, on_phase: Callable[..., None],
                abort: threading.Event) -> RunOutcome:
        from tcms_daq.acquisition import (
            DataMessage,
            EventMessage,
            ProcedureError,
            ProcedureOptions,
            ProfileRejected,
            TestRun,
        )

        payload: TestPlan | MethodTestPlan = plan.payload
        if self.acq is None:
            raise TcmsError("the bench is not open")
        extra = tuple(c for c in (plan.channels or ()) if c not in RUN_CHANNELS)
        ratio = payload.reducer.ratio
        live_te = (TeLiveFeed(ratio, on_phase) if isinstance(payload, MethodTestPlan)
                   and payload.method == "transmission-error" and ratio else None)

        def handle(msg: Any) -> None:
            if isinstance(msg, DataMessage):
                record(_columns(msg.samples, extra))
                if live_te is not None:
                    live_te.add(msg.samples)
            elif isinstance(msg, EventMessage):
                if msg.event == "state":
                    on_phase(msg.details.get("state", "?"), reason=msg.details.get("reason"))
                elif msg.event == "progress":  # times in clock seconds; clock_speed turns them into real ones
                    on_phase("progress", **msg.details,
                             clock_speed=self.sim_speed if self.bench.clock.stepped else 1.0)
                else:
                    on_phase(msg.event, **msg.details)

        self._test_waiting.set()
        try:
            self._clock_lock.acquire()
        finally:
            self._test_waiting.clear()
        try:
            # subscribed once the test has the clock: what the idle pump stepped before is not the run's (a run
            # that began with minutes of idle bench at zero torque was re-simulated from a wrong friction state)
            # lossless, delivered on its own thread; close() lets it hand over what is queued, then joins it
            sub = self.acq.fanout.subscribe_callback(handle, name=f"store-{run_id}", maxsize=None)
            if self.bench.set_specimen(payload.reducer):
                on_phase("specimen", reducer=payload.reducer.name)
            try:
                run: TestRun
                if isinstance(payload, MethodTestPlan):
                    from tcms_daq.acquisition.methodrun import MethodRun

                    run = MethodRun(
                        self.bench, payload.method_plan, reducer_torque_limit_nm=payload.reducer_torque_limit_nm,
                        evaluate=method_evaluator(self.config, self.config_path, payload), acquisition=self.acq, abort_event=abort,
                        run_id=run_id, profile_info={"reducer": payload.reducer.name},
                        options=ProcedureOptions(kept_columns=(INPUT_ANGLE_COLUMN, INPUT_TORQUE_COLUMN)))
                else:
                    run = TestRun(
                        self.bench, payload.plan if payload.plan.kind != "single" else payload.profile,
                        reducer_torque_limit_nm=payload.reducer_torque_limit_nm,
                        evaluate=self._evaluator(payload), acquisition=self.acq, abort_event=abort,
                        run_id=run_id, profile_info={"reducer": payload.reducer.name},
                        # the store records every channel as it arrives: the run keeps in memory what it evaluates
                        options=ProcedureOptions(kept_columns=(), gaps=self.config.gaps.limits()),
                    )
                result = run.run()
            except (ProfileRejected, ProcedureError) as exc:
                return RunOutcome("failed", error=str(exc))
            finally:
                # before the idle clock resumes: nothing after the run reaches the store
                sub.close(join_timeout_s=30.0)
                self._resync_clock()
        finally:
            self._clock_lock.release()
        lost = [e for e in self.acq.fanout.callback_errors if e.startswith(f"{sub.name}: ")]
        if lost:  # a sample batch or phase did not reach the store
            return RunOutcome("failed", error=f"recording failed: {lost[0]}", results=result.evaluation)
        if result.state == "completed":
            return RunOutcome("completed", results=result.evaluation)
        return RunOutcome(result.state if result.state in ("aborted", "failed") else "failed",
                          error=result.reason, results=result.evaluation)

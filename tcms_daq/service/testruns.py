"""Test execution for the service: one test at a time, each in its own worker thread.

The manager validates a request through the bench runner (422 on a bad request), refuses a second test while one
is active (409), records the run in the store, streams its samples to the recorder, publishes every state change
on the event hub and stores the outcome. The FastAPI event loop never runs acquisition or evaluation.
"""

from __future__ import annotations

import threading
import traceback
from collections.abc import Mapping
from typing import Any

from tcms_daq.errors import TcmsError
from tcms_daq.service.events import EventHub
from tcms_daq.service.runner import RequestRejected, Runner, RunOutcome
from tcms_daq.service.schemas import TestRequest
from tcms_daq.store import Recorder, Store, StoredRun, new_run_id


class Conflict(TcmsError):
    """The request conflicts with the bench state (a test is already active, the run is not active …)."""


class UnknownRun(TcmsError):
    """No run with that id."""


class TestManager:
    def __init__(self, store: Store, runner: Runner, events: EventHub, recorder_flush_s: float = 0.2):
        self.store = store
        self.runner = runner
        self.events = events
        self.recorder_flush_s = recorder_flush_s
        self._lock = threading.Lock()
        self._active_id: str | None = None
        self._abort = threading.Event()
        self._thread: threading.Thread | None = None
        self.runs_started = 0

    @property
    def active_id(self) -> str | None:
        return self._active_id

    def submit(self, request: TestRequest, *, user: str | None = None,
               plan_ref: Mapping[str, Any] | None = None) -> StoredRun:
        """Validate, store as ``queued`` and start a test. Raises RequestRejected (422) or Conflict (409).
        ``user``: who started it; ``plan_ref``: the saved plan it came from (name, version, id); both are kept
        in the run's request (its identity: ``user``, ``plan``)."""
        plan = self.runner.plan(request)  # raises RequestRejected with a one-line reason
        stored_request = request.model_dump(exclude_none=True)
        if user is not None:
            stored_request["user"] = user
        if plan_ref is not None:
            stored_request["plan"] = dict(plan_ref)
        with self._lock:
            if self._active_id is not None:
                raise Conflict(f"test {self._active_id} is still active; abort it or wait for it to finish")
            not_ready = getattr(self.runner, "not_ready_reason", None)
            reason = not_ready() if not_ready is not None else None
            if reason is not None:  # e.g. the safe start found the drive enabled and could not disable it yet
                raise Conflict(reason)
            run_id = new_run_id()
            record = self.store.create_run(
                run_id,
                stored_request,
                getattr(plan, "channels", None) or self.runner.channels,
                profile=plan.profile_summary,
                config_snapshot={**self.runner.config_snapshot(),
                                 "bench_model_version": (m[0].version if (m := self.store.bench_model()) else 0)},
                compensator_toml=self.runner.compensator_toml(),
                compensation_version=(latest[0].version if (latest := self.store.compensation()) else None),
            )
            self._active_id = run_id
            self._abort = threading.Event()
            self.runs_started += 1
            self.events.publish("test_state", id=run_id, status="queued", request=record.request)
            self._thread = threading.Thread(
                target=self._execute, args=(run_id, plan, self._abort), name=f"test-{run_id}", daemon=True
            )
            self._thread.start()
        return record

    def abort(self, run_id: str, reason: str = "aborted by the operator") -> StoredRun:
        record = self.store.get_run(run_id)
        if record is None:
            raise UnknownRun(f"no test with id {run_id!r}")
        with self._lock:
            if self._active_id != run_id:
                raise Conflict(f"test {run_id} is not active (status {record.status})")
            self._abort.reason = reason  # type: ignore[attr-defined]
            self._abort.set()
        self.events.publish("abort_requested", id=run_id, reason=reason)
        return record

    def wait_idle(self, timeout_s: float | None = None) -> bool:
        thread = self._thread
        if thread is not None:
            thread.join(timeout_s)
            return not thread.is_alive()
        return True

    def shutdown(self, timeout_s: float = 10.0) -> None:
        """Abort an active test (the bench ramps down) and wait for its worker."""
        active = self._active_id
        if active is not None:
            try:
                self.abort(active, reason="service shutting down")
            except (Conflict, UnknownRun):
                pass
        self.wait_idle(timeout_s)

    # -- worker thread ---------------------------------------------------------------------------------------
    def _execute(self, run_id: str, plan: Any, abort: threading.Event) -> None:
        recorder = Recorder(self.store, run_id, flush_interval_s=self.recorder_flush_s)

        def on_phase(phase: str, **detail: Any) -> None:
            if phase == "progress":  # loop, loops, position, positions, elapsed_s, eta_s (see TestRun)
                detail.pop("run_id", None)
                self.events.publish("test_progress", id=run_id, **detail)
            elif phase in ("method_progress", "te_live"):  # a turning test's (docs/transmission.md, the contract)
                detail.pop("run_id", None)
                self.events.publish(phase, id=run_id, **detail)
            else:
                self.events.publish("test_phase", id=run_id, phase=phase, **detail)

        self.store.set_status(run_id, "running")
        self.events.publish("test_state", id=run_id, status="running")
        try:
            outcome = self.runner.execute(plan, run_id=run_id, record=recorder.write, on_phase=on_phase,
                                         abort=abort)
        except TcmsError as exc:
            outcome = RunOutcome(status="failed", error=str(exc))
        except Exception as exc:  # an internal bug must still end the run visibly, not leave it 'running'
            traceback.print_exc()
            outcome = RunOutcome(status="failed", error=f"internal error: {type(exc).__name__}: {exc}")
        try:
            recorder.close()
        except Exception as exc:
            outcome = RunOutcome(status="failed", error=f"recording failed: {exc}", results=outcome.results)
        if outcome.status == "aborted" and outcome.error is None:
            outcome = RunOutcome("aborted", getattr(abort, "reason", "aborted"), outcome.results)
        with self._lock:  # status and the active slot change together: 'completed' means a new test may start
            self.store.set_status(run_id, outcome.status, error=outcome.error, results=outcome.results)
            self._active_id = None
        self.events.publish(
            "test_state",
            id=run_id,
            status=outcome.status,
            error=outcome.error,
            results=outcome.results,
            sample_count=recorder.samples_written,
        )


__all__ = ["Conflict", "RequestRejected", "TestManager", "UnknownRun"]

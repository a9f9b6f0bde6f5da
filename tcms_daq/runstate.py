"""The one vocabulary of test-run states, shared by the procedure (``tcms_daq.acquisition``), the run store and
the API. A ``StrEnum``: the values are the strings the store and the JSON carry."""

from __future__ import annotations

from enum import StrEnum


class RunState(StrEnum):
    QUEUED = "queued"  # accepted by the service, waiting for the bench
    IDLE = "idle"  # a procedure built, not started
    PREPARING = "preparing"  # enable the drive, tare
    LOADING = "loading"  # the profile's setpoints
    EVALUATING = "evaluating"
    RUNNING = "running"  # the store's summary of preparing / loading / evaluating
    COMPLETED = "completed"
    ABORTED = "aborted"  # an interlock or an operator; the bench was ramped down and disabled
    FAILED = "failed"  # anything else (the reason says what)
    INTERRUPTED = "interrupted"  # the service stopped while the run was active (found at the next start)


# The procedure's state machine: every allowed transition; any state but a final one may end aborted/failed.
PROCEDURE_TRANSITIONS: dict[RunState, tuple[RunState, ...]] = {
    RunState.IDLE: (RunState.PREPARING, RunState.ABORTED, RunState.FAILED),
    RunState.PREPARING: (RunState.LOADING, RunState.ABORTED, RunState.FAILED),
    RunState.LOADING: (RunState.EVALUATING, RunState.ABORTED, RunState.FAILED),
    RunState.EVALUATING: (RunState.COMPLETED, RunState.FAILED, RunState.ABORTED),
    RunState.COMPLETED: (),
    RunState.ABORTED: (),
    RunState.FAILED: (),
}
PROCEDURE_FINAL: tuple[RunState, ...] = (RunState.COMPLETED, RunState.ABORTED, RunState.FAILED)

# What the run store records for a run.
STORED: tuple[RunState, ...] = (RunState.QUEUED, RunState.RUNNING, RunState.COMPLETED, RunState.ABORTED,
                                RunState.FAILED, RunState.INTERRUPTED)
STORED_ACTIVE: tuple[RunState, ...] = (RunState.QUEUED, RunState.RUNNING)
STORED_FINAL: tuple[RunState, ...] = (RunState.COMPLETED, RunState.ABORTED, RunState.FAILED, RunState.INTERRUPTED)

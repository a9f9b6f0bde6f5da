"""The record of one test run: states with times and reasons, the samples, the evaluation.

Kept apart from the procedure that fills it (bluesky's plan/engine/documents split): the service stores it,
``tcms run`` prints it as JSON.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from tcms_daq.runstate import PROCEDURE_FINAL, PROCEDURE_TRANSITIONS, RunState
from tcms_daq.samples import Samples

# The procedure's states and transitions, from the one vocabulary of run states.
IDLE, PREPARING, LOADING, EVALUATING = RunState.IDLE, RunState.PREPARING, RunState.LOADING, RunState.EVALUATING
COMPLETED, ABORTED, FAILED = RunState.COMPLETED, RunState.ABORTED, RunState.FAILED
FINAL_STATES = PROCEDURE_FINAL
TRANSITIONS = PROCEDURE_TRANSITIONS


@dataclass(frozen=True)
class StateChange:
    """Entering ``state`` at ``time_s`` (acquisition clock) / ``wall_time`` (Unix s), with an optional reason."""

    state: RunState
    time_s: float
    wall_time: float
    reason: str | None = None

    def to_dict(self) -> dict[str, Any]:
        return {"state": self.state, "time_s": self.time_s, "wall_time": self.wall_time, "reason": self.reason}


def _empty_samples() -> Samples:
    return Samples(np.empty(0), np.empty(0), np.empty(0), {"encoder_arcsec": np.empty(0), "loop_index": np.empty(0)})


@dataclass
class RunRecord:
    """Everything a run produced. ``reason`` says why it ended aborted/failed (None when completed).

    samples: every aligned, compensated sample acquired during the run (also after a trip, while ramping
    down); ``loading_window_s``: the (start, end) clock times of the loading phase, the part evaluated.
    """

    run_id: str
    bench_name: str = "bench"
    state: RunState = IDLE
    reason: str | None = None
    history: list[StateChange] = field(default_factory=list)
    samples: Samples = field(default_factory=_empty_samples)
    evaluation: dict[str, Any] | None = None
    trip: dict[str, Any] | None = None
    profile: dict[str, Any] = field(default_factory=dict)
    limits: dict[str, Any] = field(default_factory=dict)
    loading_window_s: tuple[float, float] | None = None
    loader_final: dict[str, Any] | None = None
    notes: list[str] = field(default_factory=list)
    acquisition: dict[str, Any] = field(default_factory=dict)
    started_wall: float = field(default_factory=time.time)
    finished_wall: float | None = None

    @property
    def finished(self) -> bool:
        return self.state in FINAL_STATES

    def loading_samples(self) -> Samples:
        if self.loading_window_s is None:
            return self.samples
        t0, t1 = self.loading_window_s
        return self.samples.select((self.samples.time_s >= t0) & (self.samples.time_s <= t1))

    def evaluated_samples(self) -> Samples:
        """The samples of the evaluated loops (loop_index ≥ 1), or the loading phase if no loop is marked."""
        loop = self.samples.extra.get("loop_index")
        if loop is not None and np.any(loop >= 1):
            return self.samples.select(loop >= 1)
        return self.loading_samples()

    def to_dict(self, include_samples: bool = False) -> dict[str, Any]:
        out: dict[str, Any] = {
            "run_id": self.run_id,
            "bench": self.bench_name,
            "state": self.state,
            "reason": self.reason,
            "history": [h.to_dict() for h in self.history],
            "samples_count": len(self.samples),
            "evaluation": self.evaluation,
            "trip": self.trip,
            "profile": self.profile,
            "limits": self.limits,
            "loading_window_s": list(self.loading_window_s) if self.loading_window_s else None,
            "loader_final": self.loader_final,
            "notes": list(self.notes),
            "acquisition": self.acquisition,
            "started_wall": self.started_wall,
            "finished_wall": self.finished_wall,
        }
        if include_samples:
            out["samples"] = {k: v.tolist() for k, v in self.samples.columns().items()}
        return out

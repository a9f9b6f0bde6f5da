"""The record of one test run: states with times and reasons, the samples, the evaluation.

Kept apart from the procedure that fills it (bluesky's plan/engine/documents split): the service stores it,
``tcms run`` prints it as JSON.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from tcms_daq.runstate import PROCEDURE_FINAL, PROCEDURE_TRANSITIONS, RunState
from tcms_daq.samples import CANONICAL_COLUMNS, Samples

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


class SampleBuffer:
    """A run's samples gathered batch by batch into fixed-size column chunks (no per-batch objects kept).

    ``append`` copies a batch in (called from the acquisition thread: quick, never blocks on a copy of the
    whole run); ``to_samples`` joins the chunks one column at a time, so the peak is the run plus one column,
    and returns views of the joined arrays. ``columns`` names the columns kept (the canonical three are always
    kept); None keeps those of the first batch. A batch without a kept column gets NaN there; columns not kept
    are ignored.
    """

    def __init__(self, columns: tuple[str, ...] | None = None, chunk_samples: int = 65_536):
        if chunk_samples < 1:
            raise ValueError("chunk_samples must be >= 1")
        self.chunk_samples = chunk_samples
        self._wanted = None if columns is None else tuple(dict.fromkeys((*CANONICAL_COLUMNS, *columns)))
        self._names: tuple[str, ...] = ()
        self._sealed: dict[str, list[np.ndarray]] = {}  # full or closed chunks, never written again
        self._open: dict[str, np.ndarray] = {}  # the chunk being filled
        self._open_n = 0
        self._len = 0
        self._lock = threading.Lock()

    def __len__(self) -> int:
        return self._len

    def append(self, samples: Samples) -> None:
        cols = samples.columns()
        n = len(samples)
        with self._lock:
            if not self._names:
                self._names = self._wanted or tuple(cols)
                self._sealed = {k: [] for k in self._names}
            done = 0
            while done < n:
                if not self._open:
                    size = max(self.chunk_samples, n - done)
                    self._open = {k: np.empty(size) for k in self._names}
                    self._open_n = 0
                size = len(self._open[self._names[0]])
                take = min(n - done, size - self._open_n)
                for k in self._names:
                    col = cols.get(k)
                    dst = self._open[k][self._open_n : self._open_n + take]
                    dst[:] = col[done : done + take] if col is not None else np.nan
                self._open_n += take
                done += take
                if self._open_n == size:
                    self._seal_open()
            self._len += n

    def _seal_open(self) -> None:
        for k in self._names:
            self._sealed[k].append(self._open[k][: self._open_n])
        self._open = {}
        self._open_n = 0

    def to_samples(self) -> Samples:
        """Everything appended so far, as one :class:`Samples` (views of the joined chunks)."""
        with self._lock:
            if self._open_n:
                self._seal_open()
            counts = {k: len(v) for k, v in self._sealed.items()}
        if not self._names:
            return Samples(np.empty(0), np.empty(0), np.empty(0))
        for k in self._names:
            with self._lock:
                parts = self._sealed[k][: counts[k]]
            joined = parts[0] if len(parts) == 1 else np.concatenate(parts) if parts else np.empty(0)
            del parts
            with self._lock:  # the chunks sealed meanwhile stay behind the joined one
                self._sealed[k][: counts[k]] = [joined]
        cols = {k: self._sealed[k][0] if counts[k] else np.empty(0) for k in self._names}
        return Samples(cols.pop("time_s"), cols.pop("torque_nm"), cols.pop("angle_arcsec"), cols)


def empty_samples() -> Samples:
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
    samples: Samples = field(default_factory=empty_samples)
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
        if loop is None:
            return self.loading_samples()
        evaluated = np.flatnonzero(loop >= 1)
        if not len(evaluated):
            return self.loading_samples()
        first, last = int(evaluated[0]), int(evaluated[-1])
        if last - first + 1 == len(evaluated):  # the loops follow each other: views, no copy of the run
            return self.samples.select(slice(first, last + 1))
        return self.samples.select(loop >= 1)

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

"""The one place where the service touches the bench, the procedure and the evaluation.

The service needs a small surface (:class:`Runner`): open the bench and stream every acquired batch to a sink
(the live hub), validate a test request into a plan, execute a plan in the calling (worker) thread while
recording its batches, abort, report the bench state, and get/replace the compensator. :class:`BenchRunner`
implements it over the acquisition layer; swapping the procedure implementation is a change to this file only.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from tcms_daq.errors import TcmsError
from tcms_daq.service.schemas import TestRequest

Columns = Mapping[str, np.ndarray]
BatchSink = Callable[[Columns], None]

# Channels recorded for every run (the canonical columns plus the raw encoder angle).
RUN_CHANNELS: tuple[str, ...] = ("time_s", "torque_nm", "angle_arcsec", "encoder_arcsec")


class RequestRejected(TcmsError):
    """A test request the bench cannot run (unknown reducer, torque above a limit …): HTTP 422."""


@dataclass
class TestPlan:
    """A validated request: the profile summary stored with the run, and the runner's own plan object."""

    request: TestRequest
    profile_summary: dict[str, Any]
    payload: Any = None


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

    def plan(self, request: TestRequest) -> TestPlan: ...

    def execute(
        self,
        plan: TestPlan,
        *,
        record: BatchSink,
        on_phase: Callable[..., None],
        abort: threading.Event,
    ) -> RunOutcome: ...


@dataclass
class _Subscribers:
    live: BatchSink | None = None
    record: BatchSink | None = None
    lock: threading.Lock = field(default_factory=threading.Lock)


class BenchRunner:
    """Placeholder until the acquisition layer lands (replaced in the next commit)."""

    channels = RUN_CHANNELS

    @classmethod
    def from_config(cls, config_path: Path | None, sim_speed: float = 1.0) -> BenchRunner:
        raise TcmsError("the bench runner needs tcms_daq.acquisition (not available yet)")

"""A small in-process runner: feeds a Profile to a simulated bench and records the samples batch by batch.

It talks to anything with the SimulatedBench command API (``set_drive_enabled``, ``set_torque_target``,
``advance``, ``now_s``). Every exit — normal end, error, interrupt — ramps the torque to zero and disables the
drive. The recording carries an extra ``loop_index`` column (−1 outside loops, 0 conditioning, 1…N evaluated).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Protocol

import numpy as np

from tcms_daq.procedure.profiles import OUTSIDE_LOOPS, Profile
from tcms_daq.samples import Samples

#: simulated time per recorded batch (s)
DEFAULT_BATCH_S = 0.5


class SimBenchLike(Protocol):
    @property
    def now_s(self) -> float: ...

    def set_drive_enabled(self, enabled: bool) -> None: ...

    def set_torque_target(self, target_nm: float, slope_nm_per_s: float | None = None) -> None: ...

    def advance(self, duration_s: float) -> Samples: ...


def _tag(batch: Samples, loop_index: int) -> Samples:
    batch.extra["loop_index"] = np.full(len(batch), float(loop_index))
    return batch


def run_stiffness_test(
    bench: SimBenchLike,
    profile: Profile,
    on_batch: Callable[[Samples], None] | None = None,
    progress: Callable[[float, float], None] | None = None,
    batch_s: float = DEFAULT_BATCH_S,
    settle_s: float = 0.1,
) -> Samples:
    """Run ``profile`` on ``bench`` and return all samples (with ``loop_index``), conditioning loop included.

    on_batch(samples): called with every recorded batch. progress(done_s, total_s): profile time done/total.
    The evaluated part is ``evaluated_samples(result)``.
    """
    total_s = profile.duration_s()
    done_s = 0.0
    parts: list[Samples] = []

    def record(duration_s: float, loop_index: int, callbacks: bool = True) -> None:
        nonlocal done_s
        remaining = duration_s
        while remaining > 1e-12:
            dt = min(batch_s, remaining)
            batch = _tag(bench.advance(dt), loop_index)
            remaining -= dt
            done_s += dt
            if len(batch):
                parts.append(batch)
                if on_batch is not None and callbacks:
                    on_batch(batch)
            if progress is not None and callbacks:
                progress(min(done_s, total_s), total_s)

    peak = 0.0  # the largest |demand| the present segment can have reached
    completed = False
    bench.set_drive_enabled(True)
    try:
        level = 0.0
        for seg in profile.segments:
            peak = max(abs(level), abs(seg.target_nm))
            bench.set_torque_target(seg.target_nm, seg.slope_nm_per_s)
            record(seg.duration_s(level), seg.loop_index)
            level = seg.target_nm
            peak = abs(level)
        completed = True
    finally:
        # Every exit ramps to zero at the profile rate, lets the torque loop settle and disables the drive. After
        # an error the callbacks are not called again (they may be what failed).
        try:
            bench.set_torque_target(0.0, profile.rate_nm_per_s)
            if peak > 0.0:
                record(peak / profile.rate_nm_per_s, OUTSIDE_LOOPS, callbacks=completed)
            if settle_s > 0 and math.isfinite(settle_s):
                record(settle_s, OUTSIDE_LOOPS, callbacks=completed)
        finally:
            bench.set_drive_enabled(False)
    return Samples.concat(parts)


def evaluated_samples(samples: Samples) -> Samples:
    """The samples of the evaluated loops (loop_index ≥ 1)."""
    idx = samples.extra.get("loop_index")
    if idx is None:
        return samples
    return samples.select(idx >= 1)

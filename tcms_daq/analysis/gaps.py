"""Gaps in the data: never evaluate across them (issue 22).

An instrument that is power-cycled, a link that drops and reconnects, a stalled channel: the aligned record then
has a stretch where one channel has no readings of its own. The angle channel is the time base, so an angle gap is
a long step in ``time_s``; the torque is interpolated onto the angle stamps (``tcms_daq.acquisition.align``), so a
torque gap is only visible in the interval between the two torque readings that bracketed each angle reading
(the ``torque_interval_s`` column the aligner adds). A stretch longer than the limit is a gap.

Pure functions: ``find_gaps`` (the gaps of a record), ``exclude_gapped_loops`` (the record without the loops that
hold a gap, the warnings naming each gap, and the reason when too few loops are left). The loops are the
procedure's (``loop_index`` column; ``stage_index`` for a test at several positions or rates): a whole loop is left
out, from tip to tip, so the loops that remain join at a turning point and no loop is made across the gap.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from tcms_daq.analysis.notices import Notice
from tcms_daq.samples import Samples

__all__ = ["TORQUE_INTERVAL_COLUMN", "Gap", "GapExclusion", "GapLimits", "exclude_gapped_loops", "find_gaps"]

#: per aligned sample: time between the torque readings that bracket it (s); 0 when a reading has its stamp
TORQUE_INTERVAL_COLUMN = "torque_interval_s"


@dataclass(frozen=True)
class GapLimits:
    """What a gap is (the bench config's ``[gaps]``, ``tcms_daq.config.models.GapSettings``, validated there).

    limit_s: the longest stretch without readings of a channel that is not a gap (s, clock time); None:
    ``limit_periods`` of the channel's median reading period, at least ``min_limit_s``. min_loops: the fewest
    evaluated loops (per stage) a run must keep, once the loops with a gap are left out, to complete."""

    limit_s: float | None = None
    limit_periods: float = 5.0
    min_limit_s: float = 0.2
    min_loops: int = 1

    def limit_for(self, periods_s: np.ndarray) -> float:
        """The gap limit (s) of a channel whose reading periods (s) are ``periods_s``."""
        if self.limit_s is not None:
            return self.limit_s
        periods = np.asarray(periods_s, dtype=float)
        finite = periods[np.isfinite(periods)]  # zeros count: torque readings stamped with the angle's
        typical = float(np.median(finite)) if finite.size else 0.0
        return max(self.limit_periods * typical, self.min_limit_s)


@dataclass(frozen=True)
class Gap:
    """A stretch of ``channel`` ("angle" or "torque") without readings from ``start_s`` to ``end_s`` (clock s),
    while the torque went over ``torque_lo_nm`` … ``torque_hi_nm``."""

    channel: str
    start_s: float
    end_s: float
    torque_lo_nm: float
    torque_hi_nm: float

    @property
    def duration_s(self) -> float:
        return self.end_s - self.start_s

    def describe(self) -> str:
        return (f"{self.channel} channel: no readings for {self.duration_s:.2f} s "
                f"(t = {self.start_s:.2f} … {self.end_s:.2f} s, torque {self.torque_lo_nm:.0f} … "
                f"{self.torque_hi_nm:.0f} N·m)")


def _runs(flags: np.ndarray) -> list[tuple[int, int]]:
    """(first, last) index of each run of True in ``flags``."""
    edges = np.diff(np.concatenate([[0], flags.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1, strict=True))


def find_gaps(time_s: np.ndarray, torque_nm: np.ndarray, torque_interval_s: np.ndarray | None = None,
              settings: GapLimits = GapLimits(), contiguous: np.ndarray | None = None) -> list[Gap]:
    """The gaps of an aligned record (angle stamps ``time_s``, torque ``torque_nm``), in time order.
    ``contiguous`` (one per step between samples): False where the record was cut on purpose (the move between
    two stages of a test was not kept): no gap there."""
    t = np.asarray(time_s, dtype=float)
    torque = np.asarray(torque_nm, dtype=float)
    gaps: list[Gap] = []
    if t.size >= 2:
        steps = np.diff(t)
        joined = np.ones(steps.size, dtype=bool) if contiguous is None else np.asarray(contiguous, dtype=bool)
        limit = settings.limit_for(steps[joined])
        for i in np.flatnonzero((steps > limit) & joined):
            pair = torque[i:i + 2]
            gaps.append(Gap("angle", float(t[i]), float(t[i + 1]), float(pair.min()), float(pair.max())))
    if torque_interval_s is not None and t.size:
        interval = np.asarray(torque_interval_s, dtype=float)
        limit = settings.limit_for(interval)
        for first, last in _runs(interval > limit):
            # the readings that bracket the stretch: its torque range is what was interpolated across
            lo, hi = max(first - 1, 0), min(last + 1, t.size - 1)
            span = torque[lo:hi + 1]
            start = float(t[lo]) if first > 0 else float(t[first] - interval[first])
            gaps.append(Gap("torque", start, float(t[hi]), float(span.min()), float(span.max())))
    return sorted(gaps, key=lambda g: g.start_s)


@dataclass
class GapExclusion:
    """The record to evaluate (``samples``: the loops without a gap), a warning per left-out loop naming its gaps,
    the loops left out as (stage, loop) and, when too few loops are left, the ``reason`` the run cannot complete."""

    samples: Samples
    gaps: list[Gap] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    excluded: list[tuple[int, int]] = field(default_factory=list)
    reason: str | None = None


def exclude_gapped_loops(samples: Samples, settings: GapLimits = GapLimits()) -> GapExclusion:
    """Leave out every evaluated loop (``loop_index`` ≥ 1) that holds a gap (or touches one: a gap between two
    loops leaves both out). Without a ``loop_index`` column a gap leaves nothing to evaluate."""
    interval = samples.extra.get(TORQUE_INTERVAL_COLUMN)
    loop = samples.extra.get("loop_index")
    contiguous = None
    if loop is not None:  # the loops of a stage follow each other; between stages the record was cut (a move)
        stage_of = np.asarray(samples.extra.get("stage_index", np.zeros(len(loop))), dtype=float)
        step = np.diff(np.asarray(loop, dtype=float))
        contiguous = (np.diff(stage_of) == 0) & ((step == 0) | (step == 1))
    gaps = find_gaps(samples.time_s, samples.torque_nm, interval, settings, contiguous)
    if not gaps:
        return GapExclusion(samples)
    t = samples.time_s
    if loop is None:
        return GapExclusion(samples, gaps, [f"gap: {g.describe()}" for g in gaps],
                            reason=f"a gap in the data: {gaps[0].describe()}; nothing left to evaluate")
    stage = samples.extra.get("stage_index", np.zeros(len(t)))
    keys = np.stack([np.asarray(stage, dtype=float), np.asarray(loop, dtype=float)], axis=1)
    evaluated = keys[:, 1] >= 1
    held: dict[tuple[int, int], list[Gap]] = {}
    for gap in gaps:
        touching = evaluated & (t >= gap.start_s) & (t <= gap.end_s)
        for s, k in {(int(a), int(b)) for a, b in keys[touching]}:
            held.setdefault((s, k), []).append(gap)
    if not held:  # the gaps are outside the evaluated loops
        return GapExclusion(samples, gaps)
    drop = np.zeros(len(t), dtype=bool)
    warnings: list[str] = []
    for (s, k), loop_gaps in sorted(held.items()):
        drop |= (keys[:, 0] == s) & (keys[:, 1] == k)
        described = "; ".join(g.describe() for g in loop_gaps)
        if "stage_index" in samples.extra:
            warnings.append(Notice("loop_of_stage_left_out_gap", "loop {loop} of stage {stage} left out, not "
                                   "evaluated across a gap: {gaps}", loop=str(k), stage=str(s + 1), gaps=described))
        else:
            warnings.append(Notice("loop_left_out_gap", "loop {loop} left out, not evaluated across a gap: {gaps}",
                                   loop=str(k), gaps=described))
    reason = None
    for s in np.unique(keys[evaluated, 0]):
        in_stage = evaluated & (keys[:, 0] == s)
        total = np.unique(keys[in_stage, 1]).size
        left = np.unique(keys[in_stage & ~drop, 1]).size
        if left < settings.min_loops:
            where = f" in stage {int(s) + 1}" if "stage_index" in samples.extra else ""
            reason = (f"{left} of {total} loops{where} left after leaving out the loops with a gap "
                      f"(at least {settings.min_loops} needed): {warnings[0]}")
            break
    return GapExclusion(samples.select(~drop), gaps, warnings, sorted(held), reason)

"""Gaps in the data: never evaluate across them (issue 22).

An instrument that is power-cycled, a link that drops and reconnects, a stalled channel: the aligned record then
has a stretch where one channel has no readings of its own. The angle channel is the time base, so an angle gap is
a long step in ``time_s``; the torque is interpolated onto the angle stamps (``tcms_daq.acquisition.align``), so a
torque gap is only visible in the interval between the two torque readings that bracketed each angle reading
(the ``torque_interval_s`` column the aligner adds). A stretch longer than the limit is a gap. A change of the
angle's datum (the ``angle_datum`` column: the ND 287 was power-cycled and counts from a new zero) is a break in
the angle channel whatever its length: the angles on its two sides are not comparable. So is a step of the angle
between two joined readings larger than the reducer can twist in that time at the run's torque rate (an "angle
jump": a display whose datum was reset without its link dropping, ``find_angle_jumps``).

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

__all__ = ["ANGLE_DATUM_COLUMN", "TOO_FEW_LOOPS_LEFT", "TORQUE_INTERVAL_COLUMN", "Gap", "GapExclusion", "GapLimits", "exclude_gapped_loops",
           "find_angle_jumps", "find_gaps"]

#: per aligned sample: time between the torque readings that bracket it (s); 0 when a reading has its stamp
TORQUE_INTERVAL_COLUMN = "torque_interval_s"
#: per angle reading: the datum it counts from (the power cycles of the angle display its driver noticed)
ANGLE_DATUM_COLUMN = "angle_datum"
TOO_FEW_LOOPS_LEFT = "left after leaving out the loops with a gap"  # in the reason of a run that cannot complete


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
    #: an angle jump: a step above ``jump_factor`` × the compliance there × torque rate × time step + the floor
    jump_factor: float = 5.0
    jump_floor_arcsec: float = 1.0
    jump_span_fraction: float = 0.05  # and above this share of the record's angle span

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
    #: "no readings" (a gap), "new datum" (the readings after it count from another zero), "angle jump"
    kind: str = "no readings"
    step_arcsec: float = 0.0  # an angle jump: the step, and the largest step the physics allows there
    allowed_arcsec: float = 0.0

    @property
    def duration_s(self) -> float:
        return self.end_s - self.start_s

    def describe(self) -> Notice:
        """What the gap is, where and when, in words (a coded notice: the pages translate it)."""
        span = "(t = {t_from} … {t_to} s, torque {torque_lo} … {torque_hi} N·m)"
        params = {"channel": self.channel, "t_from": f"{self.start_s:.2f}", "t_to": f"{self.end_s:.2f}",
                  "torque_lo": f"{self.torque_lo_nm:.0f}", "torque_hi": f"{self.torque_hi_nm:.0f}"}
        if self.kind == "angle jump":
            return Notice("gap_angle_jump", "{channel} channel: a step of {step}″ in {duration} s, where at most "
                          "{allowed}″ is plausible at this torque rate (the display's datum changed?) " + span,
                          step=f"{self.step_arcsec:+.1f}", duration=f"{self.duration_s:.3f}",
                          allowed=f"{self.allowed_arcsec:.1f}", **params)
        duration = f"{self.duration_s:.2f}"
        if self.kind == "new datum":
            return Notice("gap_new_datum", "{channel} channel: new datum (the display was power-cycled and counts from "
                          "another zero) between two readings {duration} s apart " + span, duration=duration, **params)
        no_readings = "{channel} channel: no readings for {duration} s " + span
        if self.channel == "torque":
            return Notice("gap_torque_no_readings", no_readings, duration=duration, **params)
        return Notice("gap_angle_no_readings", no_readings, duration=duration, **params)


def _runs(flags: np.ndarray) -> list[tuple[int, int]]:
    """(first, last) index of each run of True in ``flags``."""
    edges = np.diff(np.concatenate([[0], flags.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1, strict=True))


def find_gaps(time_s: np.ndarray, torque_nm: np.ndarray, torque_interval_s: np.ndarray | None = None,
              settings: GapLimits = GapLimits(), contiguous: np.ndarray | None = None,
              angle_datum: np.ndarray | None = None) -> list[Gap]:
    """The gaps of an aligned record (angle stamps ``time_s``, torque ``torque_nm``), in time order.
    ``contiguous`` (one per step between samples): False where the record was cut on purpose (the move between
    two stages of a test was not kept): no gap there. ``angle_datum`` (per sample): a change between two joined
    samples is a "new datum" break of the angle channel, however short."""
    t = np.asarray(time_s, dtype=float)
    torque = np.asarray(torque_nm, dtype=float)
    gaps: list[Gap] = []
    if t.size >= 2:
        steps = np.diff(t)
        joined = np.ones(steps.size, dtype=bool) if contiguous is None else np.asarray(contiguous, dtype=bool)
        limit = settings.limit_for(steps[joined])
        new_datum = np.zeros(steps.size, dtype=bool)
        if angle_datum is not None:
            change = np.diff(np.asarray(angle_datum, dtype=float))
            new_datum = np.isfinite(change) & (change != 0)  # NaN: a sample without the column, no change known
        for i in np.flatnonzero(((steps > limit) | new_datum) & joined):
            pair = torque[i:i + 2]
            gaps.append(Gap("angle", float(t[i]), float(t[i + 1]), float(pair.min()), float(pair.max()),
                            "new datum" if new_datum[i] else "no readings"))
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


def find_angle_jumps(time_s: np.ndarray, torque_nm: np.ndarray, angle_arcsec: np.ndarray,
                     settings: GapLimits = GapLimits(), contiguous: np.ndarray | None = None) -> list[Gap]:
    """Steps of the angle between two joined readings larger than the physics allows: the reducer twists at most
    by its compliance at that torque × the torque change between them (the torque rate × the time between them,
    or the measured change if larger), with ``jump_factor`` for margin and ``jump_floor_arcsec`` for the noise, and
    at least ``jump_span_fraction`` of the record's angle span. The compliance at a torque is the record's own:
    Σ|Δangle| / Σ|Δtorque| over the steps in that torque band (20 bands over the 1st–99th percentiles; the largest
    of a band and its neighbours, so the lost-motion band's high compliance covers its edges); the rate the
    record's 95th-percentile torque rate; the time at least the median reading period (stamps jitter). Pure; []
    for a record too short or without a torque span."""
    t = np.asarray(time_s, dtype=float)
    torque = np.asarray(torque_nm, dtype=float)
    angle = np.asarray(angle_arcsec, dtype=float)
    if t.size < 40:
        return []
    dt, d_torque, d_angle = np.diff(t), np.diff(torque), np.diff(angle)
    joined = np.ones(dt.size, dtype=bool) if contiguous is None else np.asarray(contiguous, dtype=bool)
    torque_lo, torque_hi = np.percentile(torque, [1, 99])
    if not torque_hi - torque_lo > 0 or np.count_nonzero(joined) < 20:
        return []
    period = float(np.median(dt[joined]))
    rate = float(np.percentile(np.abs(d_torque[joined]) / np.maximum(dt[joined], period), 95))  # N·m/s
    step_torque, step_angle = np.abs(d_torque), np.abs(d_angle)
    n_bands = 20
    band = np.clip(((torque[:-1] + torque[1:]) / 2 - torque_lo) / (torque_hi - torque_lo) * n_bands, 0,
                   n_bands - 1).astype(int)

    # compliance as Σ|Δangle| / Σ|Δtorque| of the steps, a ratio of sums, not of single steps: readings repeat when
    # an instrument is polled faster than it updates (the angle then moves in a few of them; a jump in a band at
    # most doubles it, the margin of ``jump_factor`` covers that). A band with fewer than 5 steps or no torque
    # change takes the record's overall compliance.
    total_torque = float(step_torque[joined].sum())
    if not total_torque > 0:
        return []
    overall = float(step_angle[joined].sum()) / total_torque
    steps_in = np.bincount(band[joined], minlength=n_bands)
    torque_in = np.bincount(band[joined], weights=step_torque[joined], minlength=n_bands)
    angle_in = np.bincount(band[joined], weights=step_angle[joined], minlength=n_bands)
    usable = (steps_in >= 5) & (torque_in > 0)
    per_band = np.where(usable, angle_in / np.where(usable, torque_in, 1.0), overall)
    padded = np.concatenate([[per_band[0]], per_band, [per_band[-1]]])
    compliance = np.maximum(np.maximum(padded[:-2], padded[1:-1]), padded[2:])  # arcsec per N·m, per band
    # the torque change a step may carry: at the run's rate over its time, or the measured one (readings that
    # bunch up after a stall carry a larger change than their stamps say)
    torque_change = np.maximum(rate * np.maximum(dt, period), step_torque)
    angle_lo, angle_hi = np.percentile(angle, [1, 99])
    allowed = np.maximum(settings.jump_factor * compliance[band] * torque_change + settings.jump_floor_arcsec,
                         settings.jump_span_fraction * (angle_hi - angle_lo))
    jumps = []
    for i in np.flatnonzero(joined & (np.abs(d_angle) > allowed)):
        pair = torque[i:i + 2]
        jumps.append(Gap("angle", float(t[i]), float(t[i + 1]), float(pair.min()), float(pair.max()), "angle jump",
                         float(d_angle[i]), float(allowed[i])))
    return jumps


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
    datum = samples.extra.get(ANGLE_DATUM_COLUMN)
    gaps = find_gaps(samples.time_s, samples.torque_nm, interval, settings, contiguous, datum)
    jumps = find_angle_jumps(samples.time_s, samples.torque_nm, samples.angle_arcsec, settings, contiguous)
    if jumps:  # a jump is a datum change nobody announced: the loops on its two sides are joined like those
        step_at = np.searchsorted(samples.time_s, [j.end_s for j in jumps])
        unannounced = np.zeros(len(samples))
        unannounced[step_at] = 1.0
        known = np.zeros(len(samples)) if datum is None else np.nan_to_num(np.asarray(datum, dtype=float))
        samples = Samples(samples.time_s, samples.torque_nm, samples.angle_arcsec,
                          {**samples.extra, ANGLE_DATUM_COLUMN: known + np.cumsum(unannounced)})
        gaps = sorted(gaps + jumps, key=lambda g: g.start_s)
    if not gaps:
        return GapExclusion(samples)
    t = samples.time_s
    if loop is None:
        return GapExclusion(samples, gaps, [Notice("gap", "gap: {gap}", gap=g.describe()) for g in gaps],
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
        described = [g.describe() for g in loop_gaps]
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
            reason = (f"{left} of {total} loops{where} {TOO_FEW_LOOPS_LEFT} "
                      f"(at least {settings.min_loops} needed): {warnings[0]}")
            break
    kept, notes = _join_datums(samples.select(~drop))
    return GapExclusion(kept, gaps, warnings + notes, sorted(held), reason)


def _join_datums(samples: Samples) -> tuple[Samples, list[str]]:
    """The kept loops with the angles of each later datum shifted to continue the earlier one where two kept loops
    join (a turning point: the loops that held the datum change are left out, so the loops on its two sides meet
    at the tip between them); a warning per shift. Within a stage only: stages are evaluated apart."""
    datum = samples.extra.get(ANGLE_DATUM_COLUMN)
    if datum is None or len(samples) < 2:
        return samples, []
    stage = np.asarray(samples.extra.get("stage_index", np.zeros(len(samples))), dtype=float)
    change = np.diff(np.asarray(datum, dtype=float))
    joins = np.flatnonzero(np.isfinite(change) & (change != 0) & (np.diff(stage) == 0))
    if not joins.size:
        return samples, []
    angle = np.array(samples.angle_arcsec, dtype=float)
    notes: list[str] = []
    for j in joins:
        shift = angle[j] - angle[j + 1]
        same_stage = stage == stage[j]
        angle[j + 1:][same_stage[j + 1:]] += shift
        notes.append(Notice("angle_datum_joined", "angle channel: the loops from t = {time} s count from a new datum; "
                            "their angles are joined to the earlier loops at the turning point where they meet "
                            "(torque {torque} N·m, shifted by {shift}″)", time=f"{samples.time_s[j + 1]:.2f}",
                            torque=f"{samples.torque_nm[j]:.0f}", shift=f"{shift:+.1f}"))
    return Samples(samples.time_s, samples.torque_nm, angle, dict(samples.extra)), notes

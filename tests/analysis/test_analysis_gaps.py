"""Gaps in the data (issue 22): a stretch of a channel without readings is found, named (channel, time span,
torque range), and the loop that holds it is left out of the evaluation; too few loops left is a reason not to
complete. The records are made from a spring with a friction band (not from the code under test)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tcms_daq.acquisition.align import Aligner
from tcms_daq.analysis import evaluate
from tcms_daq.analysis.gaps import (
    ANGLE_DATUM_COLUMN,
    TORQUE_INTERVAL_COLUMN,
    GapLimits,
    exclude_gapped_loops,
    find_angle_jumps,
    find_gaps,
)
from tcms_daq.analysis.notices import notices_of
from tcms_daq.samples import Samples
from tcms_daq.service.messages import notice_text

RATE_HZ = 500.0
T_MAX = 1000.0
RIGIDITY = 300.0  # N·m/arcmin
FRICTION_ARCSEC = 8.0
FRICTION_TURN_NM = 40.0
LOOP_S = 8.0  # −T → +T → −T at 500 N·m/s


def loops_record(n_loops: int) -> Samples:
    """n_loops loops from −T (loop_index 1…n), preceded by the ramp from 0 to −T (loop_index −1)."""
    t = np.arange(0.0, 2.0 + n_loops * LOOP_S, 1 / RATE_HZ)
    lead = t < 2.0
    phase = ((t - 2.0) % LOOP_S) / LOOP_S
    torque = np.where(lead, -T_MAX * t / 2.0, T_MAX * (1 - 4 * np.abs(phase - 0.5)))
    rising = np.where(lead, False, phase < 0.5)
    # the friction turns over within FRICTION_TURN_NM of each turning point (a reducer does not jump at a tip)
    from_tip = np.where(rising, torque + T_MAX, T_MAX - torque)
    friction = np.where(rising, -1.0, 1.0) * FRICTION_ARCSEC / 2 * (1 - 2 * np.exp(-from_tip / FRICTION_TURN_NM))
    angle = torque / RIGIDITY * 60.0 + np.where(lead, FRICTION_ARCSEC / 2, friction)
    loop = np.where(lead, -1.0, np.floor((t - 2.0) / LOOP_S) + 1)
    return Samples(t, torque, angle, {"loop_index": loop, TORQUE_INTERVAL_COLUMN: np.zeros(t.size)})


def without(samples: Samples, start_s: float, end_s: float) -> Samples:
    return samples.select(~((samples.time_s > start_s) & (samples.time_s < end_s)))


def test_an_angle_gap_is_named_and_its_loop_left_out():
    record = without(loops_record(3), 12.0, 13.2)  # in loop 2, on the way up from 0 to 600 N·m
    gaps = find_gaps(record.time_s, record.torque_nm, record.extra[TORQUE_INTERVAL_COLUMN])
    assert len(gaps) == 1
    gap = gaps[0]
    assert gap.channel == "angle" and gap.start_s == pytest.approx(12.0) and gap.end_s == pytest.approx(13.2)
    assert gap.torque_lo_nm == pytest.approx(0, abs=2) and gap.torque_hi_nm == pytest.approx(600, abs=2)
    evaluated = record.select(record.extra["loop_index"] >= 1)
    out = exclude_gapped_loops(evaluated)
    assert out.reason is None and out.excluded == [(0, 2)]
    assert len(out.warnings) == 1 and "loop 2 left out" in out.warnings[0]
    assert "angle channel: no readings for 1.20 s" in out.warnings[0] and "torque 0 … 600 N·m" in out.warnings[0]
    assert set(np.unique(out.samples.extra["loop_index"])) == {1.0, 3.0}
    ev = evaluate(out.samples.time_s, out.samples.torque_nm, out.samples.angle_arcsec, rated_torque_nm=T_MAX)
    clean = loops_record(3)
    clean = clean.select(clean.extra["loop_index"] >= 1)
    reference = evaluate(clean.time_s, clean.torque_nm, clean.angle_arcsec, rated_torque_nm=T_MAX)
    assert ev.n_loops == 2  # the two loops joined at their turning point, no loop made across the cut
    assert ev.rigidity_nm_per_arcmin == pytest.approx(reference.rigidity_nm_per_arcmin, rel=5e-3)
    assert ev.lost_motion_arcsec == pytest.approx(reference.lost_motion_arcsec, abs=0.5)


def with_new_datum(samples: Samples, at_s: float) -> Samples:
    """The angle display power-cycled at ``at_s`` with no gap in its readings: from there it counts from 0 where it
    was switched on (its datum lost), and each reading carries the datum it counts from."""
    after = samples.time_s >= at_s
    offset = -samples.angle_arcsec[np.argmax(after)]
    angle = np.where(after, samples.angle_arcsec + offset, samples.angle_arcsec)
    return Samples(samples.time_s, samples.torque_nm, angle,
                   {**samples.extra, ANGLE_DATUM_COLUMN: after.astype(float)})


def test_a_new_datum_is_a_break_however_short_and_its_loop_is_left_out():
    record = with_new_datum(loops_record(3), 12.6)  # in loop 2, on the way up at 300 N·m, no reading missing
    gaps = find_gaps(record.time_s, record.torque_nm, angle_datum=record.extra[ANGLE_DATUM_COLUMN])
    assert len(gaps) == 1 and gaps[0].kind == "new datum" and gaps[0].channel == "angle"
    assert gaps[0].start_s == pytest.approx(12.6, abs=0.01) and gaps[0].duration_s < 0.01
    assert gaps[0].torque_lo_nm == pytest.approx(300, abs=2) and gaps[0].torque_hi_nm == pytest.approx(300, abs=2)
    evaluated = record.select(record.extra["loop_index"] >= 1)
    out = exclude_gapped_loops(evaluated)
    assert out.reason is None and out.excluded == [(0, 2)]
    assert "loop 2 left out" in out.warnings[0] and "angle channel: new datum" in out.warnings[0]
    assert "t = 12.60 … 12.60 s" in out.warnings[0]
    assert len(out.warnings) == 2 and "count from a new datum" in out.warnings[1]  # loops 1 and 3 joined at −T
    # in Chinese from their codes, the gap inside the left-out loop's warning too (as the store keeps them)
    zh = [notice_text(n, "zh") for n in json.loads(json.dumps(notices_of(out.warnings)))]
    assert zh[0].startswith("第 2 个循环含数据间隙，未参与评定：角度通道：新基准") and "t = 12.60 … 12.60 s" in zh[0]
    assert zh[1].startswith("角度通道：自 t = ") and "channel" not in " ".join(zh), zh
    assert [notice_text(n, "en") for n in notices_of(out.warnings)] == out.warnings
    # the loop after it counts from the new datum throughout: evaluated, and the rigidity is the clean one's
    ev = evaluate(out.samples.time_s, out.samples.torque_nm, out.samples.angle_arcsec, rated_torque_nm=T_MAX)
    clean = loops_record(3)
    clean = clean.select(clean.extra["loop_index"] >= 1)
    reference = evaluate(clean.time_s, clean.torque_nm, clean.angle_arcsec, rated_torque_nm=T_MAX)
    assert ev.n_loops == 2
    assert ev.rigidity_nm_per_arcmin == pytest.approx(reference.rigidity_nm_per_arcmin, rel=5e-3)
    # the same record with the datum only changing back and forth nowhere (NaN: a batch without the column)
    unknown = np.where(record.time_s < 5.0, np.nan, 0.0)
    assert find_gaps(record.time_s, record.torque_nm, angle_datum=unknown) == []


def test_an_angle_jump_without_a_datum_change_is_a_break_too():
    """The display's datum reset while its link stayed up (no datum column says so): the angle steps by more than
    the reducer can twist in one reading period at this torque rate; the loop is left out naming the step."""
    record = with_new_datum(loops_record(3), 12.6)
    record = Samples(record.time_s, record.torque_nm, record.angle_arcsec,
                     {k: v for k, v in record.extra.items() if k != ANGLE_DATUM_COLUMN})
    jumps = find_angle_jumps(record.time_s, record.torque_nm, record.angle_arcsec)
    assert len(jumps) == 1 and jumps[0].kind == "angle jump"
    assert jumps[0].step_arcsec == pytest.approx(-(300 / RIGIDITY * 60 - FRICTION_ARCSEC / 2), abs=1.0)
    assert jumps[0].allowed_arcsec < 25.0  # 5 % of the record's 430″ span (5 × 0.2″/N·m × 1 N·m + 1″ is less)
    out = exclude_gapped_loops(record.select(record.extra["loop_index"] >= 1))
    assert out.reason is None and out.excluded == [(0, 2)]
    assert "angle channel: a step of -55.8″ in 0.002 s" in out.warnings[0], out.warnings
    clean = loops_record(3)
    clean = clean.select(clean.extra["loop_index"] >= 1)
    assert find_angle_jumps(clean.time_s, clean.torque_nm, clean.angle_arcsec) == []
    ev = evaluate(out.samples.time_s, out.samples.torque_nm, out.samples.angle_arcsec, rated_torque_nm=T_MAX)
    reference = evaluate(clean.time_s, clean.torque_nm, clean.angle_arcsec, rated_torque_nm=T_MAX)
    assert ev.n_loops == 2
    assert ev.rigidity_nm_per_arcmin == pytest.approx(reference.rigidity_nm_per_arcmin, rel=5e-3)


def test_a_torque_gap_is_seen_in_the_torque_interval():
    record = loops_record(2)
    interval = record.extra[TORQUE_INTERVAL_COLUMN]
    hole = (record.time_s > 3.0) & (record.time_s < 4.5)  # no torque readings: interpolated over 1.5 s
    interval[hole] = 1.5
    gaps = find_gaps(record.time_s, record.torque_nm, interval)
    assert [g.channel for g in gaps] == ["torque"]
    assert gaps[0].start_s == pytest.approx(3.0) and gaps[0].end_s == pytest.approx(4.5)
    out = exclude_gapped_loops(record.select(record.extra["loop_index"] >= 1))
    assert out.excluded == [(0, 1)] and "torque channel" in out.warnings[0]


def test_too_few_loops_left_is_a_reason_and_no_gap_changes_nothing():
    record = loops_record(1)
    evaluated = record.select(record.extra["loop_index"] >= 1)
    assert exclude_gapped_loops(evaluated).samples is evaluated  # clean: the same record
    out = exclude_gapped_loops(without(evaluated, 5.0, 6.0))
    assert out.reason is not None and out.reason.startswith("0 of 1 loops left")
    assert "angle channel: no readings for 1.00 s" in out.reason
    # a configured limit above the gap lets it pass; a sampling jitter of a few periods is no gap
    assert exclude_gapped_loops(without(evaluated, 5.0, 6.0), GapLimits(limit_s=2.0)).reason is None
    jitter = without(evaluated, 5.0, 5.0 + 4 / RATE_HZ)
    assert find_gaps(jitter.time_s, jitter.torque_nm) == []


def test_a_gap_between_stages_names_the_stage():
    record = loops_record(2)
    stage = np.where(record.time_s < 10.0, 0.0, 1.0)
    loop = np.where(record.time_s < 10.0, 1.0, 1.0)
    staged = Samples(record.time_s, record.torque_nm, record.angle_arcsec,
                     {"loop_index": loop, "stage_index": stage, TORQUE_INTERVAL_COLUMN: np.zeros(record.time_s.size)})
    out = exclude_gapped_loops(without(staged, 14.0, 15.0))
    assert out.excluded == [(1, 1)] and "stage 2" in out.warnings[0] and "stage 2" in (out.reason or "")


def test_the_aligner_carries_the_torque_interval():
    aligner = Aligner(max_wait_s=0.5)
    torque_t = np.array([0.0, 0.01, 0.02, 1.5, 1.51])  # no torque readings from 0.02 to 1.5 s
    angle_t = np.array([0.005, 0.01, 0.5, 1.0, 1.505])
    t, _, _ = aligner.push(angle_t, angle_t * 0, torque_t, torque_t * 0, now_s=1.6)
    interval = aligner.released_extra[TORQUE_INTERVAL_COLUMN]
    assert t.tolist() == angle_t.tolist()
    assert interval == pytest.approx([0.01, 0.0, 1.48, 1.48, 0.01])
    stale = Aligner(max_wait_s=0.5)
    stale.push(np.array([0.0]), np.zeros(1), np.array([0.0]), np.zeros(1), now_s=0.0)
    stale.push(np.array([0.9]), np.zeros(1), np.empty(0), np.empty(0), now_s=1.5)  # torque stalled
    assert stale.released_extra[TORQUE_INTERVAL_COLUMN] == pytest.approx([1.5])


def test_the_cut_between_two_stages_is_no_gap():
    """A test at several positions keeps each stage's loops; the move between them is not evaluated, so the
    record jumps in time there: that is no gap."""
    first, second = loops_record(1), loops_record(1)
    later = Samples(second.time_s + 60.0, second.torque_nm, second.angle_arcsec, dict(second.extra))
    both = Samples.concat([first, later])
    stage = np.concatenate([np.zeros(first.time_s.size), np.ones(later.time_s.size)])
    staged = Samples(both.time_s, both.torque_nm, both.angle_arcsec, {**both.extra, "stage_index": stage})
    evaluated = staged.select(staged.extra["loop_index"] >= 1)
    out = exclude_gapped_loops(evaluated)
    assert out.gaps == [] and out.reason is None and out.samples is evaluated

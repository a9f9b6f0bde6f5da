"""A run's progress events: before each step of a profile or plan (and once after the last), which loop, stage
and position it is at, the clock time elapsed and an estimate of the time left. Split from the test run's state
machine (``testrun.py``), which only says when a step begins."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

from tcms_daq.acquisition.fanout import FanOut
from tcms_daq.procedure.plan import Move, Plan
from tcms_daq.procedure.profiles import OUTSIDE_LOOPS, Segment


class RunProgress:
    """The progress of one run: its planned step durations (clock s; a plan's from where the output is at the
    start, ``start_position_deg``, None: 0°) and the clock time it started loading (``t_start_s``)."""

    def __init__(self, run_id: str, plan: Plan | None, segments: Sequence[Segment], t_start_s: float,
                 start_position_deg: float | None = None):
        self.run_id = run_id
        self.plan = plan
        self.segments = list(segments)
        self.t_start_s = t_start_s
        if plan is not None:
            here = plan if start_position_deg is None else replace(plan, start_position_deg=start_position_deg)
            self.step_durations_s = here.step_durations_s()
        else:
            self.step_durations_s = [seg.duration_s(prev.target_nm if prev is not None else 0.0)
                                     for prev, seg in zip([None, *self.segments[:-1]], self.segments, strict=True)]

    def publish(self, fanout: FanOut, now_s: float, number: int, stage: int, step: Move | Segment | None) -> None:
        """A ``progress`` event before step ``number`` (and one after the last, ``step`` None): the loop (0 the
        conditioning, −1 outside the loops or moving) of ``loops`` evaluated ones, the position (1-based) of
        ``positions``, the stage of ``stages``, the elapsed clock time and an ETA (clock s): the planned time
        left, scaled by how much longer than planned the steps so far took."""
        elapsed = now_s - self.t_start_s
        planned_done = sum(self.step_durations_s[:number])
        left = sum(self.step_durations_s[number:])
        pace = min(max(elapsed / planned_done, 1.0), 3.0) if planned_done > 1.0 else 1.0
        plan = self.plan
        stages = plan.stages if plan is not None else ()
        current = stages[stage] if 0 <= stage < len(stages) else None
        positional = plan is not None and plan.kind == "positions"
        profile = current.profile if current is not None else (plan.first if plan is not None else None)
        fanout.publish_event(
            "progress", now_s, run_id=self.run_id,
            step=number, steps=len(self.step_durations_s),
            loop=(OUTSIDE_LOOPS if step is None or isinstance(step, Move) else step.loop_index),
            loops=profile.cycles if profile is not None else max((s.loop_index for s in self.segments), default=0),
            moving=isinstance(step, Move),
            position=(stage + 1 if positional and stage >= 0 else (len(stages) if positional else 1)),
            positions=len(stages) if positional else 1,
            position_deg=(current.position_deg if current is not None else None),
            stage=stage + 1 if stage >= 0 else max(len(stages), 1), stages=max(len(stages), 1),
            rate_nm_per_s=current.rate_nm_per_s if current is not None else None,
            elapsed_s=elapsed, eta_s=left * pace,
        )

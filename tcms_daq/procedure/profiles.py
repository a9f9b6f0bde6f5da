"""Stiffness-test loading profiles as data (pure): a list of segments the loader works through.

GB-style sequence (DESIGN §2): from zero torque go to −T (the approach, not part of any loop), then every loop is
−T → 0 → +T → 0 → −T (or mirrored, starting at +T). The first ``conditioning_loops`` loops condition the reducer
(recorded, marked with loop index 0), the next ``cycles`` loops are evaluated (loop index 1…N); at the end the
torque returns to zero (loop index −1, like the approach).

Continuous profile: one ramp at the loading rate through each quarter (no stop at zero), a dwell at ±T.
Stepped profile: equal torque steps (``step_nm``; the last step of a quarter may be shorter) at the loading rate,
each followed by a dwell of ``dwell_s``.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from tcms_daq.config.models import BenchSection, ReducerSpec, TestProfile

#: loop index of samples outside every loop (the approach to −T and the final return to zero)
OUTSIDE_LOOPS = -1
#: loop index of the conditioning loop(s)
CONDITIONING = 0


@dataclass(frozen=True)
class Segment:
    """Ramp the torque demand to ``target_nm`` at ``slope_nm_per_s``, then hold for ``dwell_s``."""

    target_nm: float
    slope_nm_per_s: float
    dwell_s: float
    loop_index: int

    def ramp_s(self, from_nm: float) -> float:
        return abs(self.target_nm - from_nm) / self.slope_nm_per_s

    def duration_s(self, from_nm: float) -> float:
        return self.ramp_s(from_nm) + self.dwell_s


@dataclass(frozen=True)
class Profile:
    """A generated profile: the parameters it was made from and its segments (in order)."""

    kind: str
    test_torque_nm: float
    rate_nm_per_s: float
    cycles: int
    conditioning_loops: int
    step_nm: float | None
    dwell_s: float
    tip_dwell_s: float
    start: str
    segments: tuple[Segment, ...] = field(repr=False)

    def duration_s(self, from_nm: float = 0.0) -> float:
        """Total time of the profile (s) starting at ``from_nm``, ignoring the drive lag."""
        total, level = 0.0, from_nm
        for seg in self.segments:
            total += seg.duration_s(level)
            level = seg.target_nm
        return total

    @property
    def mean_rate_nm_per_s(self) -> float:
        """Average torque rate while loading, dwells included (equals the rate for a continuous profile)."""
        if self.kind == "continuous":
            return self.rate_nm_per_s
        step = float(self.step_nm)  # type: ignore[arg-type]
        return step / (step / self.rate_nm_per_s + self.dwell_s)

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d.pop("segments")
        d["mean_rate_nm_per_s"] = self.mean_rate_nm_per_s
        d["duration_s"] = self.duration_s()
        return d


def gb_waypoints(test_torque_nm: float, cycles: int, conditioning_loops: int = 1, start: str = "negative"
                 ) -> list[tuple[float, int]]:
    """The GB-style sequence as (target torque, loop index) waypoints, including the approach and the return."""
    if test_torque_nm <= 0:
        raise ValueError(f"test torque must be > 0 (got {test_torque_nm})")
    if cycles < 1 or conditioning_loops < 0:
        raise ValueError("cycles must be >= 1 and conditioning_loops >= 0")
    t = test_torque_nm if start == "positive" else -test_torque_nm
    points: list[tuple[float, int]] = [(t, OUTSIDE_LOOPS)]
    for i in range(conditioning_loops + cycles):
        idx = CONDITIONING if i < conditioning_loops else i - conditioning_loops + 1
        points += [(0.0, idx), (-t, idx), (0.0, idx), (t, idx)]
    points.append((0.0, OUTSIDE_LOOPS))
    return points


def continuous_profile(test_torque_nm: float, rate_nm_per_s: float, cycles: int = 3, conditioning_loops: int = 1,
                       tip_dwell_s: float = 0.2, start: str = "negative") -> Profile:
    """Constant torque rate through the whole GB sequence, a dwell of ``tip_dwell_s`` at ±T."""
    if rate_nm_per_s <= 0:
        raise ValueError(f"loading rate must be > 0 N·m/s (got {rate_nm_per_s})")
    segs = [
        Segment(target, rate_nm_per_s, tip_dwell_s if target != 0.0 else 0.0, idx)
        for target, idx in gb_waypoints(test_torque_nm, cycles, conditioning_loops, start)
    ]
    return Profile("continuous", float(test_torque_nm), float(rate_nm_per_s), cycles, conditioning_loops, None,
                   0.0, tip_dwell_s, start, tuple(segs))


def _levels_between(a: float, b: float, step: float) -> list[float]:
    """Levels from a (exclusive) to b (inclusive) on the grid k·step (plus b itself)."""
    lo, hi = min(a, b), max(a, b)
    k = np.arange(np.floor(lo / step) + 1, np.ceil(hi / step), dtype=float) * step
    grid = [float(x) for x in k if lo < x < hi and not np.isclose(x, lo) and not np.isclose(x, hi)]
    levels = sorted(grid) if b > a else sorted(grid, reverse=True)
    return levels + [b]


def stepped_profile(test_torque_nm: float, step_nm: float, dwell_s: float, rate_nm_per_s: float, cycles: int = 3,
                    conditioning_loops: int = 1, tip_dwell_s: float | None = None, start: str = "negative"
                    ) -> Profile:
    """Equal torque steps on the grid k·step_nm (±T included) at the loading rate, a dwell at every level."""
    if step_nm <= 0 or rate_nm_per_s <= 0:
        raise ValueError("step_nm and rate_nm_per_s must be > 0")
    tip = dwell_s if tip_dwell_s is None else max(dwell_s, tip_dwell_s)
    segs: list[Segment] = []
    level = 0.0
    for target, idx in gb_waypoints(test_torque_nm, cycles, conditioning_loops, start):
        if target == level:
            continue
        for lv in _levels_between(level, target, step_nm):
            segs.append(Segment(lv, rate_nm_per_s, tip if abs(lv) == test_torque_nm else dwell_s, idx))
        level = target
    return Profile("stepped", float(test_torque_nm), float(rate_nm_per_s), cycles, conditioning_loops,
                   float(step_nm), float(dwell_s), tip, start, tuple(segs))


def default_rate_nm_per_s(test_torque_nm: float) -> float:
    """Default loading rate: a quarter of the test torque per second (a loop of ±T takes 16 s of sim time)."""
    return 0.25 * test_torque_nm


def build_profile(test: TestProfile, reducer: ReducerSpec | None = None) -> Profile:
    """A Profile from a TestProfile config (max torque default: the reducer's rated torque)."""
    torque = test.max_torque_nm
    if torque is None:
        if reducer is None:
            raise ValueError("max_torque_nm is needed when no reducer is given")
        torque = reducer.rated_torque_nm
    rate = test.rate_nm_per_s if test.rate_nm_per_s is not None else default_rate_nm_per_s(torque)
    if test.kind == "stepped":
        return stepped_profile(torque, test.step_nm, test.dwell_s, rate, test.cycles, test.conditioning_loops,
                               test.tip_dwell_s, test.start)
    return continuous_profile(torque, rate, test.cycles, test.conditioning_loops, test.tip_dwell_s, test.start)


def check_test_bounds(test: TestProfile, test_torque_nm: float, bench: BenchSection) -> None:
    """ValueError (one line naming the field) when a test would leave the bench's bounds: a loading rate outside
    [min, max], a step below the smallest, more segments than the bench takes, or a test longer than the longest.
    Checked before the profile is built (a 1e-9 N·m step would otherwise allocate terabytes)."""
    rate = test.rate_nm_per_s if test.rate_nm_per_s is not None else default_rate_nm_per_s(test_torque_nm)
    for name, value in (("max_torque_nm", test_torque_nm), ("rate_nm_per_s", rate), ("step_nm", test.step_nm),
                        ("dwell_s", test.dwell_s), ("tip_dwell_s", test.tip_dwell_s)):
        if not math.isfinite(value):
            raise ValueError(f"{name} must be a finite number, got {value}")
    if rate < bench.min_rate_nm_per_s:
        raise ValueError(f"rate_nm_per_s {rate:g} N·m/s is below the bench's slowest rate "
                         f"{bench.min_rate_nm_per_s:g} N·m/s")
    if rate > bench.rate_limit_nm_per_s:
        raise ValueError(f"rate_nm_per_s {rate:g} N·m/s exceeds the bench's fastest rate "
                         f"{bench.rate_limit_nm_per_s:g} N·m/s")
    loops = test.cycles + test.conditioning_loops
    segments = 4 * loops + 1
    if test.kind == "stepped":
        if test.step_nm < bench.min_step_nm:
            raise ValueError(f"step_nm {test.step_nm:g} N·m is below the bench's smallest step {bench.min_step_nm:g} N·m")
        segments = math.ceil(4 * loops * test_torque_nm / test.step_nm) + 1
        if segments > bench.max_segments:
            raise ValueError(f"step_nm {test.step_nm:g} N·m makes {segments} steps; the bench takes at most "
                             f"{bench.max_segments} (a larger step or fewer cycles)")
    dwell = (test.dwell_s if test.kind == "stepped" else 0.0) * segments + test.tip_dwell_s * 2 * loops
    duration_s = 4 * loops * test_torque_nm / rate + dwell
    if duration_s > bench.max_test_duration_s:
        raise ValueError(f"the test would take {duration_s / 3600:.3g} h; the bench's longest test is "
                         f"{bench.max_test_duration_s / 3600:.3g} h (rate_nm_per_s {rate:g} N·m/s)")

"""Split a torque record into hysteresis branches and full loops.

A turning point is the torque extremum between two crossings of opposite Schmitt thresholds (±½ of the
torque scale), so noise near a threshold cannot create spurious branches. A branch runs from one turning
point to the next: B↑ (direction +1) from a negative to a positive turning point, B↓ (direction −1) from a
positive to a negative one. The partial branch from the unloaded start to the first turning point and the
unloading ramp after the last one are not branches. A loop is a pair of consecutive full branches (B↑ B↓ or
B↓ B↑).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tcms_daq.errors import EvaluationError

SCHMITT_FRACTION = 0.5  # thresholds at ±50 % of the torque scale
TIP_VALID_FRACTION = 0.9  # a turning point below 90 % of the typical one is a partial (aborted) ramp


@dataclass(frozen=True)
class TurningPoint:
    index: int
    torque_nm: float  # smoothed torque at the extremum
    sign: int  # +1 positive extremum, −1 negative


@dataclass(frozen=True)
class Branch:
    """Samples ``start``…``stop`` (both inclusive, both turning points) of one branch."""

    start: int
    stop: int
    direction: int  # +1: B↑ (towards +T), −1: B↓ (towards −T)
    start_torque_nm: float
    stop_torque_nm: float

    @property
    def slice(self) -> slice:
        return slice(self.start, self.stop + 1)

    def progress_nm(self, torque_smooth_nm: np.ndarray) -> np.ndarray:
        """How far the branch has come (N·m, in its own direction): the running maximum of direction × the
        smoothed torque over its samples — non-decreasing, so levels are found by ``searchsorted``."""
        return np.maximum.accumulate(self.direction * torque_smooth_nm[self.slice])


@dataclass(frozen=True)
class Loop:
    first: Branch
    second: Branch

    @property
    def up(self) -> Branch:
        return self.first if self.first.direction > 0 else self.second

    @property
    def down(self) -> Branch:
        return self.first if self.first.direction < 0 else self.second

    @property
    def order(self) -> str:
        return "up-down" if self.first.direction > 0 else "down-up"

    def reached_torque_nm(self, sign: int) -> float:
        """Smallest |torque| of this loop's turning points on one side (where both branches exist)."""
        ends = [
            abs(t)
            for b in (self.first, self.second)
            for t in (b.start_torque_nm, b.stop_torque_nm)
            if np.sign(t) == sign
        ]
        return float(min(ends))


def turning_points(torque_smooth_nm: np.ndarray, scale_nm: float) -> list[TurningPoint]:
    """Alternating extrema of the (smoothed) torque between crossings of ±SCHMITT_FRACTION·scale."""
    threshold = SCHMITT_FRACTION * scale_nm
    state = np.zeros(torque_smooth_nm.size, dtype=np.int8)
    state[torque_smooth_nm > threshold] = 1
    state[torque_smooth_nm < -threshold] = -1
    beyond = np.flatnonzero(state)
    if beyond.size == 0:
        return []
    signs = state[beyond]
    change = np.flatnonzero(np.diff(signs)) + 1
    run_first = np.concatenate(([0], change))
    run_last = np.concatenate((change, [beyond.size])) - 1
    tips: list[TurningPoint] = []
    for a, b in zip(run_first, run_last, strict=True):
        lo, hi = int(beyond[a]), int(beyond[b])
        sign = int(signs[a])
        segment = torque_smooth_nm[lo : hi + 1]
        i = lo + int(np.argmax(segment) if sign > 0 else np.argmin(segment))
        tips.append(TurningPoint(i, float(torque_smooth_nm[i]), sign))
    return tips


def segment_loops(torque_smooth_nm: np.ndarray, scale_nm: float) -> tuple[list[Branch], list[Loop]]:
    """Full branches and full loops of a record, in time order.

    Raises EvaluationError when there is no full loop (the message says what was found).
    """
    tips = turning_points(torque_smooth_nm, scale_nm)
    if len(tips) < 3:
        raise EvaluationError(
            f"no full hysteresis loop: torque has {len(tips)} turning point(s) beyond ±{SCHMITT_FRACTION:.0%} "
            f"of {scale_nm:.4g} Nm (a loop needs three: e.g. −T → +T → −T)"
        )
    typical = float(np.median([abs(t.torque_nm) for t in tips]))
    valid = [abs(t.torque_nm) >= TIP_VALID_FRACTION * typical for t in tips]
    branches: list[Branch] = []
    full: list[bool] = []
    for k in range(len(tips) - 1):
        a, b = tips[k], tips[k + 1]
        branches.append(Branch(a.index, b.index, b.sign, a.torque_nm, b.torque_nm))
        full.append(valid[k] and valid[k + 1] and b.index - a.index >= 2)
    loops: list[Loop] = []
    k = 0
    while k + 1 < len(branches):
        if full[k] and full[k + 1]:
            loops.append(Loop(branches[k], branches[k + 1]))
            k += 2
        else:
            k += 1
    if not loops:
        raise EvaluationError(
            f"no full hysteresis loop: {sum(full)} full branch(es) between ±{typical:.4g} Nm turning points "
            "(a loop needs a B↑ and a B↓ branch in a row)"
        )
    return [b for b, f in zip(branches, full, strict=True) if f], loops

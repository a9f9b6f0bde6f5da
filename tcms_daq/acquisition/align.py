"""Align torque and angle readings from separate instruments onto one time base.

The angle source is the time base: every angle reading keeps its own driver stamp, and the torque at that
instant is interpolated linearly between the two torque readings that bracket it. Why this way round: the
angle (the quantity whose small differences make the rigidity) is never resampled, so encoder quantisation
and the compensation see the raw readings, while the torque signal is smooth between readings (the loader
ramps it). An angle reading is held back until a torque reading at or after its stamp has arrived, so
interpolation never extrapolates; after ``max_wait_s`` without newer torque data (torque channel slow or
stalled) held readings are released with the latest torque (zero-order hold) rather than lost. Angle readings
stamped before the first torque reading take the first torque value.

When both channels come from one instrument (the virtual bench), the stamps coincide and the interpolation
returns the torque readings unchanged. Extra per-reading columns of the angle source (the simulation's truth)
travel with their angle readings. Each released reading also carries ``torque_interval_s``: the time between the
two torque readings its torque was interpolated from (0 when a torque reading has its stamp; for a reading
released on zero-order hold, at least the time since the last torque reading), so that a gap in the torque
channel stays visible after alignment (``tcms_daq.analysis.gaps``).
"""

from __future__ import annotations

import numpy as np

from tcms_daq.analysis.gaps import TORQUE_INTERVAL_COLUMN
from tcms_daq.drivers.base import concat_common_columns

# torque history kept for interpolation (s); older readings are never needed once angles pass them
_KEEP_S = 1.0


class Aligner:
    """Stateful, batch-wise aligner; ``push`` returns (time_s, torque_nm, angle_arcsec) ready so far, and
    ``released_extra`` holds the extra angle columns of those readings."""

    def __init__(self, max_wait_s: float = 0.5):
        self.max_wait_s = float(max_wait_s)
        self._tq_t = np.empty(0)
        self._tq_v = np.empty(0)
        self._ang_t = np.empty(0)
        self._ang_v = np.empty(0)
        self._ang_x: dict[str, np.ndarray] | None = None  # extra columns held with the angle readings

    def _hold_extra(self, extra: dict[str, np.ndarray] | None) -> None:
        extra = {k: np.asarray(v, float) for k, v in (extra or {}).items()}
        # only the columns every batch has are kept (concat_common_columns)
        self._ang_x = extra if self._ang_x is None else concat_common_columns([self._ang_x, extra])

    def _release_extra(self, n: int) -> dict[str, np.ndarray]:
        if not self._ang_x:
            return {}
        out = {k: v[:n] for k, v in self._ang_x.items()}
        self._ang_x = {k: v[n:] for k, v in self._ang_x.items()}
        return out

    def push(self, angle_t: np.ndarray, angle_v: np.ndarray, torque_t: np.ndarray, torque_v: np.ndarray,
             now_s: float, angle_extra: dict[str, np.ndarray] | None = None
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        if len(torque_t):
            order = np.argsort(torque_t, kind="stable")
            self._tq_t = np.concatenate([self._tq_t, np.asarray(torque_t, float)[order]])
            self._tq_v = np.concatenate([self._tq_v, np.asarray(torque_v, float)[order]])
        if len(angle_t):
            self._ang_t = np.concatenate([self._ang_t, np.asarray(angle_t, float)])
            self._ang_v = np.concatenate([self._ang_v, np.asarray(angle_v, float)])
            self._hold_extra(angle_extra)
        self.released_extra: dict[str, np.ndarray] = {}
        if not len(self._ang_t) or not len(self._tq_t):
            return np.empty(0), np.empty(0), np.empty(0)

        last_tq = self._tq_t[-1]
        ready = self._ang_t <= last_tq
        stale = (now_s - self._ang_t) > self.max_wait_s
        take = ready | stale
        if not take.any():
            return np.empty(0), np.empty(0), np.empty(0)
        # release in order: everything up to the last releasable reading
        t, tq, a = self._release(int(np.flatnonzero(take)[-1]) + 1, now_s)
        keep_from = np.searchsorted(self._tq_t, t[-1] - _KEEP_S)
        keep_from = min(int(keep_from), len(self._tq_t) - 2) if len(self._tq_t) >= 2 else 0
        self._tq_t = self._tq_t[max(keep_from, 0):]
        self._tq_v = self._tq_v[max(keep_from, 0):]
        return t, tq, a

    def _release(self, n: int, now_s: float = np.inf) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The first ``n`` held angle readings with their interpolated torque; their extras (and the torque
        interval of each) go to ``released_extra``."""
        t, a = self._ang_t[:n], self._ang_v[:n]
        tq = np.interp(t, self._tq_t, self._tq_v)
        self.released_extra = self._release_extra(n)
        self.released_extra[TORQUE_INTERVAL_COLUMN] = self._torque_interval(t, now_s)
        self._ang_t, self._ang_v = self._ang_t[n:], self._ang_v[n:]
        return t, tq, a

    def _torque_interval(self, t: np.ndarray, now_s: float) -> np.ndarray:
        """Time (s) between the torque readings at or before and at or after each stamp in ``t`` (0 at a torque
        stamp); after the last torque reading, ``now_s`` − that reading; before the first, infinite."""
        after = np.searchsorted(self._tq_t, t, side="left")
        before = np.searchsorted(self._tq_t, t, side="right") - 1
        n = len(self._tq_t)
        later = np.where(after < n, self._tq_t[np.minimum(after, n - 1)], max(now_s, float(self._tq_t[-1])))
        earlier = np.where(before >= 0, self._tq_t[np.maximum(before, 0)], -np.inf)
        return later - earlier

    def flush(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Release every held angle reading (end of run); without any torque reading they are discarded."""
        self.released_extra = {}
        if not len(self._ang_t) or not len(self._tq_t):
            self._ang_t = self._ang_v = np.empty(0)
            self._ang_x = None  # discarded with their angle readings
            return np.empty(0), np.empty(0), np.empty(0)
        return self._release(len(self._ang_t))

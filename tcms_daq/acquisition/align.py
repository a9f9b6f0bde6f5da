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
from tcms_daq.drivers.base import INPUT_ANGLE_COLUMN as INPUT_ANGLE
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


class StationAligner:
    """The turning tests' time base: the angle pair source's readings (output and input encoder latched together,
    :data:`~tcms_daq.drivers.base.INPUT_ANGLE_COLUMN` beside the output angle) keep their stamps; the loader's
    torque and the input torque (when the bench has it) are interpolated onto them as :class:`Aligner` does the
    torque onto the angle: a pair is held until every side channel has a reading at or after its stamp, or until
    ``max_wait_s`` has passed (then the latest reading holds). ``push`` returns the released pairs as columns:
    ``time_s``, ``output_arcsec`` (raw), ``input_angle_arcsec``, ``torque_nm`` (the loader's), ``input_torque_nm``
    (when there is an input torque channel) and ``torque_interval_s`` (the loader torque's, as :class:`Aligner`)."""

    def __init__(self, sides: tuple[str, ...] = ("torque_nm",), max_wait_s: float = 0.5):
        self.sides = sides
        self.max_wait_s = float(max_wait_s)
        self._side_t = {name: np.empty(0) for name in sides}
        self._side_v = {name: np.empty(0) for name in sides}
        self._t = np.empty(0)
        self._out = np.empty(0)
        self._in = np.empty(0)
        self._last_s = -np.inf  # the last released pair's stamp
        self.dropped = 0  # pairs dropped for a stamp out of order

    def push(self, pair_t: np.ndarray, output_arcsec: np.ndarray, input_arcsec: np.ndarray,
             side: dict[str, tuple[np.ndarray, np.ndarray]], now_s: float) -> dict[str, np.ndarray]:
        for name, (t, v) in side.items():
            if name in self._side_t and len(t):
                order = np.argsort(t, kind="stable")
                self._side_t[name] = np.concatenate([self._side_t[name], np.asarray(t, float)[order]])
                self._side_v[name] = np.concatenate([self._side_v[name], np.asarray(v, float)[order]])
        if len(pair_t):
            t = np.asarray(pair_t, float)
            # strictly increasing stamps: a pair at or before one already held or released is dropped (a card's
            # clock mapping stepped back by the link's jitter)
            last = self._t[-1] if len(self._t) else self._last_s
            keep = t > np.maximum.accumulate(np.concatenate(([last], t)))[:-1]
            self.dropped += int(np.count_nonzero(~keep))
            self._t = np.concatenate([self._t, t[keep]])
            self._out = np.concatenate([self._out, np.asarray(output_arcsec, float)[keep]])
            self._in = np.concatenate([self._in, np.asarray(input_arcsec, float)[keep]])
        if not len(self._t) or any(not len(self._side_t[name]) for name in self.sides):
            return {}
        covered = min(float(self._side_t[name][-1]) for name in self.sides)
        take = (self._t <= covered) | ((now_s - self._t) > self.max_wait_s)
        if not take.any():
            return {}
        return self._release(int(np.flatnonzero(take)[-1]) + 1, now_s)

    def _release(self, n: int, now_s: float = np.inf) -> dict[str, np.ndarray]:
        t = self._t[:n]
        self._last_s = float(t[-1])
        out: dict[str, np.ndarray] = {"time_s": t, "output_arcsec": self._out[:n], INPUT_ANGLE: self._in[:n]}
        for name in self.sides:
            st, sv = self._side_t[name], self._side_v[name]
            out[name] = np.interp(t, st, sv)
            if name == "torque_nm":
                after = np.searchsorted(st, t, side="left")
                before = np.searchsorted(st, t, side="right") - 1
                later = np.where(after < st.size, st[np.minimum(after, st.size - 1)], max(now_s, float(st[-1])))
                earlier = np.where(before >= 0, st[np.maximum(before, 0)], -np.inf)
                out[TORQUE_INTERVAL_COLUMN] = later - earlier
            keep = max(0, min(int(np.searchsorted(st, t[-1] - _KEEP_S)), st.size - 2))
            self._side_t[name], self._side_v[name] = st[keep:], sv[keep:]
        self._t, self._out, self._in = self._t[n:], self._out[n:], self._in[n:]
        return out

    def flush(self) -> dict[str, np.ndarray]:
        """Release every held pair (end of run); without a reading of every side channel they are discarded."""
        if not len(self._t) or any(not len(self._side_t[name]) for name in self.sides):
            self._t = self._out = self._in = np.empty(0)
            return {}
        return self._release(len(self._t))

"""Safety interlocks judged on every aligned batch and every loader status.

Each check is a vectorised function of a batch (no per-sample Python); the first violation becomes a
:class:`Trip` whose ``reason`` is one line a test engineer can act on. The acquisition loop checks, the
procedure aborts on the first trip (ramping the loader to zero and disabling it) and keeps the data so far.

Interlocks (DESIGN §6): torque limit (bench and reducer), angle window, torque-rate limit, stale-data
watchdog, drive fault, lost instrument.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tcms_daq.analysis.noise import white_noise_std
from tcms_daq.drivers.base import LoaderStatus


@dataclass(frozen=True)
class Trip:
    """A tripped interlock: ``interlock`` name, one-line ``reason``, clock time ``time_s``."""

    interlock: str
    reason: str
    time_s: float

    def to_dict(self) -> dict:
        return {"interlock": self.interlock, "reason": self.reason, "time_s": self.time_s}


@dataclass(frozen=True)
class InterlockLimits:
    """Limits; ``None`` disables a check. Torques in N·m, angles in arcsec, times in s.

    bench_torque_limit_nm: the bench's maximum (sensor, fixture); reducer_torque_limit_nm: the test piece's
    (catalogue). torque_rate_limit_nm_per_s is judged on the slope over ``rate_window_s`` (not sample to
    sample, which would trip on sensor noise). stale_timeout_s: longest time without a new reading per channel.
    max_consecutive_errors: failed reads of one instrument in a row before it counts as lost.
    """

    bench_torque_limit_nm: float | None = None
    reducer_torque_limit_nm: float | None = None
    angle_min_arcsec: float | None = None
    angle_max_arcsec: float | None = None
    torque_rate_limit_nm_per_s: float | None = None
    rate_window_s: float = 0.2
    stale_timeout_s: float = 1.0
    max_consecutive_errors: int = 3

    @property
    def torque_limit_nm(self) -> float:
        limits = [x for x in (self.bench_torque_limit_nm, self.reducer_torque_limit_nm) if x is not None]
        return min(limits) if limits else math.inf

    def to_dict(self) -> dict:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


def check_torque_limit(time_s: np.ndarray, torque_nm: np.ndarray, limits: InterlockLimits) -> Trip | None:
    """The first sample above the lower of the bench and reducer limits (named in the reason)."""
    candidates = [(limit, name) for name, limit in (("bench", limits.bench_torque_limit_nm),
                                                    ("reducer", limits.reducer_torque_limit_nm)) if limit is not None]
    if not candidates:
        return None
    limit, name = min(candidates)
    over = np.flatnonzero(np.abs(torque_nm) > limit)
    if over.size:
        i = int(over[0])
        return Trip("torque_limit", f"torque {torque_nm[i]:.1f} N·m exceeds the {name} limit ±{limit:g} N·m",
                    float(time_s[i]))
    return None


def check_angle_window(time_s: np.ndarray, angle_arcsec: np.ndarray, limits: InterlockLimits) -> Trip | None:
    lo = -np.inf if limits.angle_min_arcsec is None else limits.angle_min_arcsec
    hi = np.inf if limits.angle_max_arcsec is None else limits.angle_max_arcsec
    out = np.flatnonzero((angle_arcsec < lo) | (angle_arcsec > hi))
    if out.size:
        i = int(out[0])
        return Trip("angle_window", f"angle {angle_arcsec[i]:.1f}″ outside the window "
                                    f"[{lo:g}, {hi:g}]″", float(time_s[i]))
    return None


# How many standard deviations of the rate's noise the rate limit allows on top of the configured limit.
RATE_NOISE_SIGMAS = 6.0
MIN_NOISE_SAMPLES = 8


class TorqueRateMonitor:
    """Torque slope over a sliding window (N·m/s), carried across batches, judged against the configured limit
    plus an allowance for the measured sensor noise.

    The rate is the difference of two readings ``rate_window_s`` apart over their time difference; with white
    noise σ on each reading its noise is σ·√2 / window, so a quasi-static test (a 20 N·m test at 0.5 N·m/s with
    0.3 N·m of noise: ±2 N·m/s of rate noise at 0.2 s) would trip on noise alone. The limit is therefore raised by
    RATE_NOISE_SIGMAS of that noise, with σ measured on the recent readings (``white_noise_std``: blind to a
    single jump, so a real spike does not hide itself).
    """

    def __init__(self, limits: InterlockLimits):
        self.limits = limits
        self._t = np.empty(0)
        self._v = np.empty(0)
        self.noise_nm = 0.0  # the latest estimate of the torque noise (1 sigma)

    def allowance_nm_per_s(self) -> float:
        """What the measured noise adds to the limit (N·m/s)."""
        return RATE_NOISE_SIGMAS * math.sqrt(2.0) * self.noise_nm / self.limits.rate_window_s

    def check(self, time_s: np.ndarray, torque_nm: np.ndarray) -> Trip | None:
        limit = self.limits.torque_rate_limit_nm_per_s
        if limit is None or not len(time_s):
            return None
        window = self.limits.rate_window_s
        t = np.concatenate([self._t, time_s])
        v = np.concatenate([self._v, torque_nm])
        start = len(self._t)
        if len(v) >= MIN_NOISE_SAMPLES:
            self.noise_nm = white_noise_std(v)
        effective = limit + self.allowance_nm_per_s()
        # for each new sample i the first sample at least `window` earlier
        j = np.searchsorted(t, t[start:] - window, side="right") - 1
        valid = j >= 0
        trip = None
        if valid.any():
            i = np.arange(start, len(t))[valid]
            jj = j[valid]
            dt = t[i] - t[jj]
            ok = dt > 0
            rate = np.zeros_like(dt)
            rate[ok] = (v[i][ok] - v[jj][ok]) / dt[ok]
            over = np.flatnonzero(np.abs(rate) > effective)
            if over.size:
                k = int(over[0])
                trip = Trip("torque_rate", f"torque rate {rate[k]:+.4g} N·m/s over {dt[k]:.3g} s exceeds "
                                           f"±{effective:.4g} N·m/s (limit {limit:.4g} N·m/s + "
                                           f"{self.allowance_nm_per_s():.3g} N·m/s for the measured torque noise "
                                           f"{self.noise_nm:.3g} N·m)", float(t[i[k]]))
        keep = np.searchsorted(t, t[-1] - 2 * window)
        self._t, self._v = t[keep:], v[keep:]
        return trip


def check_loader_status(status: LoaderStatus) -> Trip | None:
    if status.fault or status.state.upper() == "FAULT":
        code = f" 0x{status.error_code:04X}" if status.error_code else ""
        return Trip("drive_fault", f"drive fault{code} (loader state {status.state})", status.time_s)
    return None

"""The interlock monitor: judges each published batch and each channel's freshness against a run's limits.

It only judges (returns the :class:`~.interlocks.Trip` a check found, or None); the acquisition loop decides
what a trip does (keep the first, ask the drive for a root cause, publish the event, wake the procedure).

On real time the judgement allows for the simulator's or the scheduler's jitter: the torque-rate window spans at
least 0.2 s of real time and the stale-data limit at least 0.5 s of real time, scaled by the clock's speed (a
faster-than-real-time simulator that stalls for a moment must not look like a torque jump or a lost instrument).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable
from typing import Protocol

import numpy as np

from tcms_daq.acquisition.interlocks import (
    InterlockLimits,
    TorqueRateMonitor,
    Trip,
    check_angle_window,
    check_torque_limit,
)

MIN_RATE_WINDOW_REAL_S = 0.2
# A sped-up simulated bench still talks in real time: the watchdog waits at least this long in real seconds,
# longer than an instrument request's own timeout (0.5 s in the packaged configs), so a request that fails
# ends in its driver's error (which names the cause) and a machine busy for a few hundred ms is not 'lost'.
MIN_STALE_TIMEOUT_REAL_S = 1.0


class ChannelState(Protocol):
    """What the monitor reads of one instrument channel (clock seconds)."""

    kind: str
    name: str
    last_arrival_s: float
    busy_since: float | None
    errors_in_row: int
    last_error: str | None


class InterlockMonitor:
    """``real_time_speed``: None on a stepped (simulated) clock; else simulated seconds per real second."""

    def __init__(self, limits: InterlockLimits, real_time_speed: float | None = None):
        self.real_time_speed = real_time_speed
        self.limits = limits
        self._rate = TorqueRateMonitor(self._rate_limits(limits))

    def rearm(self, limits: InterlockLimits) -> None:
        """New limits for a new run; the torque-rate history starts again."""
        self.limits = limits
        self._rate = TorqueRateMonitor(self._rate_limits(limits))

    def _rate_limits(self, limits: InterlockLimits) -> InterlockLimits:
        if self.real_time_speed is None:
            return limits
        window = max(limits.rate_window_s, MIN_RATE_WINDOW_REAL_S * self.real_time_speed)
        return dataclasses.replace(limits, rate_window_s=window)

    def judge_batch(self, time_s: np.ndarray, torque_nm: np.ndarray, angle_arcsec: np.ndarray) -> Trip | None:
        """Torque limit, angle window, torque rate (in that order; the first that trips)."""
        for trip in (check_torque_limit(time_s, torque_nm, self.limits),
                     check_angle_window(time_s, angle_arcsec, self.limits),
                     self._rate.check(time_s, torque_nm)):
            if trip is not None:
                return trip
        return None

    def stale_timeout_s(self) -> float | None:
        timeout = self.limits.stale_timeout_s
        if timeout is None or self.real_time_speed is None:
            return timeout
        return max(timeout, MIN_STALE_TIMEOUT_REAL_S * self.real_time_speed)

    def link_problem(self, ch: ChannelState, now_s: float) -> str | None:
        """What is wrong with a channel's link short of the watchdog: failed requests, a request pending for a
        tenth of the watchdog time, or no reading for half of it; None when it looks healthy."""
        timeout_s = self.stale_timeout_s()
        if ch.errors_in_row and ch.last_error:
            return f"{ch.errors_in_row} failed request(s): {ch.last_error}"
        if ch.busy_since is not None and now_s - ch.busy_since > 0.1 * (timeout_s or 1.0):
            return f"request to {ch.name} pending for {now_s - ch.busy_since:.2f} s"
        age_s = now_s - ch.last_arrival_s
        if timeout_s is not None and age_s > 0.5 * timeout_s:
            return f"no reading from {ch.name} for {age_s:.2f} s"
        return None

    def judge_freshness(self, channels: Iterable[ChannelState], now_s: float) -> Trip | None:
        """Watchdog: the first channel without a new reading for the stale timeout. A channel whose recent reads
        failed, or whose request is pending, is reported as lost (with its last error, else the pending time)."""
        timeout = self.stale_timeout_s()
        if timeout is None:
            return None
        for ch in channels:
            age = now_s - ch.last_arrival_s
            if age <= timeout:
                continue
            if ch.errors_in_row and ch.last_error:  # says more than the retry that is pending now
                return Trip("lost_instrument", f"lost {ch.kind} instrument: no reading for {age:.2f} s "
                                               f"({ch.last_error})", now_s)
            if ch.busy_since is not None:
                return Trip("lost_instrument", f"lost {ch.kind} instrument: no reading for {age:.2f} s, request to "
                                               f"{ch.name} pending for {now_s - ch.busy_since:.2f} s (watchdog "
                                               f"timeout {timeout:g} s)", now_s)
            return Trip("stale_data", f"stale data: no {ch.kind} reading from {ch.name} for {age:.2f} s "
                                      f"(limit {timeout:g} s)", now_s)
        return None

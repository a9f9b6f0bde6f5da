"""The interlock monitor on its own: batches and freshness judged without threads, instruments or clocks."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tcms_daq.acquisition.interlocks import InterlockLimits
from tcms_daq.acquisition.monitor import InterlockMonitor


@dataclass
class Channel:
    kind: str
    name: str
    last_arrival_s: float
    busy_since: float | None = None
    errors_in_row: int = 0
    last_error: str | None = None


LIMITS = InterlockLimits(bench_torque_limit_nm=100.0, angle_min_arcsec=-50.0, angle_max_arcsec=50.0,
                         stale_timeout_s=0.5)


def test_a_batch_over_the_torque_limit_trips_first():
    t = np.linspace(0.0, 0.1, 11)
    trip = InterlockMonitor(LIMITS).judge_batch(t, np.full(11, 150.0), np.full(11, 80.0))
    assert trip.interlock == "torque_limit"
    assert InterlockMonitor(LIMITS).judge_batch(t, np.full(11, 10.0), np.full(11, 80.0)).interlock == "angle_window"
    assert InterlockMonitor(LIMITS).judge_batch(t, np.full(11, 10.0), np.full(11, 5.0)) is None


def test_freshness_names_stale_pending_and_failing_channels():
    monitor = InterlockMonitor(LIMITS)
    fresh = Channel("angle", "ND 287", last_arrival_s=9.8)
    assert monitor.judge_freshness([fresh], now_s=10.0) is None
    stale = monitor.judge_freshness([fresh, Channel("torque", "AED", 9.0)], now_s=10.0)
    assert stale.interlock == "stale_data" and "AED" in stale.reason and "1.00 s" in stale.reason
    pending = monitor.judge_freshness([Channel("loader", "drive", 9.0, busy_since=9.2)], now_s=10.0)
    assert pending.interlock == "lost_instrument" and "pending for 0.80 s" in pending.reason
    failing = monitor.judge_freshness([Channel("angle", "ND 287", 9.0, errors_in_row=3, last_error="garbage")], 10.0)
    assert failing.interlock == "lost_instrument" and "(garbage)" in failing.reason


def test_real_time_allows_for_the_clock_speed():
    """At 4× real time the watchdog waits at least 1 s of real time (4 s of clock time)."""
    monitor = InterlockMonitor(LIMITS, real_time_speed=4.0)
    assert monitor.stale_timeout_s() == 4.0
    assert monitor.judge_freshness([Channel("angle", "ND 287", 6.5)], now_s=10.0) is None
    assert monitor.judge_freshness([Channel("angle", "ND 287", 5.5)], now_s=10.0) is not None
    assert InterlockMonitor(LIMITS).stale_timeout_s() == 0.5  # stepped clock: the limit as given

"""`tcms run` shows its ETA in real seconds: the test clock's seconds left scaled by how many real seconds each
clock second has taken (a simulated clock runs many times faster than the wall clock)."""

from __future__ import annotations

import pytest

from tcms_daq.cli.run import real_eta_s


def test_a_fast_simulated_clock_gives_a_short_real_eta():
    # 90 clock seconds passed in 5 real seconds (18× faster): 216 clock seconds left are 12 real seconds
    assert real_eta_s(216.0, 90.0, 5.0) == pytest.approx(12.0)


def test_a_real_time_clock_keeps_its_eta_and_no_pace_yet_means_the_clock_eta():
    assert real_eta_s(100.0, 50.0, 50.0) == pytest.approx(100.0)
    assert real_eta_s(306.0, 0.0, 0.2) is None  # no pace measured yet: no ETA in real seconds

"""The paced simulated clock after standing still: without a resync its next sleeps return at once until the
simulation has made up the real time lost (an unpaced burst); after ``resync`` it paces from where it is.

Real time is a fake (``time.monotonic`` and ``time.sleep`` of the clock's module), so nothing here waits."""

from __future__ import annotations

from types import SimpleNamespace

from tcms_daq.acquisition import SimulatedClock


class _Source:
    def __init__(self) -> None:
        self.t = 0.0

    def now_s(self) -> float:
        return self.t

    def advance(self, duration_s: float) -> None:
        self.t += duration_s


def _fake_time(monkeypatch) -> SimpleNamespace:
    fake = SimpleNamespace(now=0.0, slept=[])

    def sleep(seconds: float) -> None:
        fake.slept.append(seconds)
        fake.now += seconds

    monkeypatch.setattr("tcms_daq.acquisition.clock.time",
                        SimpleNamespace(monotonic=lambda: fake.now, sleep=sleep))
    return fake


def test_a_clock_that_stood_still_runs_unpaced_until_caught_up(monkeypatch):
    fake = _fake_time(monkeypatch)
    clock = SimulatedClock(_Source(), speed=100.0)
    fake.now += 0.5  # half a real second nobody advanced the clock (an evaluation holding it)
    for _ in range(10):
        clock.sleep(4.0)  # 40 ms of real time each, at 100x
    assert fake.slept == []  # 40 simulated seconds stepped unpaced: 50 s of them were still to make up


def test_resync_drops_the_lost_time_and_paces_from_now(monkeypatch):
    fake = _fake_time(monkeypatch)
    source = _Source()
    clock = SimulatedClock(source, speed=100.0)
    fake.now += 0.5
    clock.resync()
    for _ in range(10):
        clock.sleep(4.0)
    assert len(fake.slept) == 10 and all(abs(s - 0.04) < 1e-9 for s in fake.slept)
    assert source.t == 40.0 and clock.monotonic_at_zero_s() == 0.5

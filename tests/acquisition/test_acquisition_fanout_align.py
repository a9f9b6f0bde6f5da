"""Fan-out (lossy/lossless subscribers, events never dropped) and torque/angle alignment."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from tcms_daq.acquisition.align import Aligner
from tcms_daq.acquisition.fanout import FanOut
from tcms_daq.samples import Samples


def batch(i: int) -> Samples:
    t = np.array([float(i)])
    return Samples(t, t, t)


def test_lossy_subscriber_drops_oldest_data_and_counts_but_keeps_events():
    fan = FanOut()
    lossy = fan.subscribe("live", maxsize=3)
    lossless = fan.subscribe("recorder", maxsize=None)
    for i in range(10):
        fan.publish_data(batch(i))
        if i == 1:
            fan.publish_event("state", 0.0, state="loading")
    got = lossy.drain()
    assert [m.kind for m in got] == ["event", "data", "data", "data"]
    assert [m.samples.time_s[0] for m in got if m.kind == "data"] == [7.0, 8.0, 9.0]
    assert lossy.dropped == 7
    all_msgs = lossless.drain()
    assert len(all_msgs) == 11 and lossless.dropped == 0
    assert [m.seq for m in all_msgs] == sorted(m.seq for m in all_msgs)


def test_a_stalled_callback_does_not_block_publishing():
    fan = FanOut()
    release = threading.Event()
    received = []

    def slow(msg):
        release.wait(60)  # released by the test; the timeout only bounds a failing run
        received.append(msg)

    sub = fan.subscribe_callback(slow, maxsize=2)
    for i in range(1000):
        fan.publish_data(batch(i))
    # all 1000 published while the callback is still stuck on its first message: publishing never waited for it
    assert received == [] and not release.is_set()
    assert sub.dropped >= 990
    release.set()
    sub.close()
    assert 1 <= len(received) <= 4


def test_callback_errors_are_recorded_not_raised():
    fan = FanOut()

    def broken(msg):
        raise RuntimeError("boom")

    sub = fan.subscribe_callback(broken, name="broken")
    fan.publish_event("state", 0.0, state="preparing")
    sub.close()
    assert fan.callback_errors == ["broken: RuntimeError: boom"]


def test_aligner_interpolates_torque_onto_angle_stamps():
    al = Aligner(max_wait_s=10.0)
    tq_t = np.arange(0, 1.0001, 0.01)  # 100 Hz torque, a ramp of 100 N·m/s
    ang_t = np.arange(0.003, 1.0, 0.037)  # ~27 Hz angle on its own stamps
    t1, tq1, a1 = al.push(ang_t[:10], ang_t[:10] * 2, tq_t[:20], tq_t[:20] * 100, now_s=0.2)
    # angle readings after the last torque reading (0.19 s) are held back, not extrapolated
    assert t1.max() <= 0.19 and len(t1) == 6
    t2, tq2, a2 = al.push(ang_t[10:], ang_t[10:] * 2, tq_t[20:], tq_t[20:] * 100, now_s=1.0)
    t = np.concatenate([t1, t2])
    np.testing.assert_allclose(t, ang_t)
    np.testing.assert_allclose(np.concatenate([tq1, tq2]), ang_t * 100, atol=1e-9)
    np.testing.assert_allclose(np.concatenate([a1, a2]), ang_t * 2)


def test_aligner_releases_held_readings_when_torque_stalls():
    al = Aligner(max_wait_s=0.5)
    t, tq, a = al.push(np.array([0.1, 0.2]), np.array([1.0, 2.0]), np.array([0.0, 0.15]),
                       np.array([0.0, 15.0]), now_s=0.25)
    assert t.tolist() == [0.1]
    t, tq, a = al.push(np.empty(0), np.empty(0), np.empty(0), np.empty(0), now_s=0.8)
    assert t.tolist() == [0.2] and tq.tolist() == [15.0]  # zero-order hold on the latest torque


def test_aligner_identical_stamps_pass_through():
    al = Aligner()
    ts = np.linspace(0, 1, 11)
    t, tq, a = al.push(ts, ts * 3, ts, ts * 7 + 1, now_s=1.0)
    np.testing.assert_array_equal(t, ts)
    np.testing.assert_allclose(tq, ts * 7 + 1)
    assert al.flush()[0].size == 0


@pytest.mark.parametrize("maxsize", [0, -1])
def test_bad_queue_size_is_refused(maxsize):
    with pytest.raises(ValueError, match="queue size"):
        FanOut().subscribe("x", maxsize=maxsize)

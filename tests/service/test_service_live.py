import asyncio

import numpy as np
import pytest

from tcms_daq.service.events import EventHub
from tcms_daq.service.live import (
    FRAME_HEADER,
    LiveHub,
    decode_frame,
    encode_frame,
    minmax_rows,
    schema_message,
    with_dropped,
)


def _cols(t0: float, n: int) -> dict[str, np.ndarray]:
    t = t0 + np.arange(n) * 1e-4
    return {"time_s": t, "torque_nm": 100 * np.sin(t), "encoder_arcsec": 3 * t, "angle_arcsec": 2.9 * t}


def test_frame_round_trip_and_dropped_patch():
    cols = _cols(1234.5, 400)
    frame = encode_frame(7, cols)
    assert len(frame) == FRAME_HEADER.size + 4 * 4 * 400
    dec = decode_frame(frame)
    assert dec.sequence == 7 and dec.t0_s == 1234.5 and dec.n_samples == 400 and dec.dropped == 0
    np.testing.assert_allclose(dec.columns["time_s"], cols["time_s"], atol=1e-6)
    np.testing.assert_allclose(dec.columns["torque_nm"], cols["torque_nm"], rtol=1e-6)
    patched = decode_frame(with_dropped(frame, 12))
    assert patched.dropped == 12 and patched.sequence == 7
    np.testing.assert_array_equal(patched.columns["angle_arcsec"], dec.columns["angle_arcsec"])
    names = [c["name"] for c in schema_message(25)["channels"]]
    assert names == ["time_s", "torque_nm", "encoder_arcsec", "angle_arcsec"]
    with pytest.raises(ValueError, match="not a TCMS live frame"):
        decode_frame(b"XXXX" + frame[4:])


async def test_stalled_client_neither_blocks_others_nor_grows_memory():
    hub = LiveHub(frame_rate_hz=25, max_queue=5, stall_timeout_s=0.3)
    healthy: list[bytes] = []
    stall = asyncio.Event()  # never set: the stalled client's send blocks forever

    async def send_ok(frame: bytes) -> None:
        healthy.append(frame)

    async def send_stalled(frame: bytes) -> None:
        await stall.wait()

    ok = hub.add_client(send_ok)
    stalled = hub.add_client(send_stalled)
    tasks = [asyncio.ensure_future(ok.run()), asyncio.ensure_future(stalled.run())]
    for i in range(40):
        hub.publish(_cols(i * 0.04, 400))
        hub.tick()
        await asyncio.sleep(0.001)
    await asyncio.sleep(0.05)
    # the healthy client got every frame, in order, while the other one was stuck
    seqs = [decode_frame(f).sequence for f in healthy]
    assert seqs == list(range(1, 41))
    assert all(decode_frame(f).dropped == 0 for f in healthy)
    assert stalled.queued <= 5 and stalled.dropped == 40 - 1 - 5
    await asyncio.sleep(0.4)  # the blocked send exceeds the stall timeout -> evicted
    assert stalled.evicted and tasks[1].done()
    hub.remove_client(stalled)
    assert hub.evicted_total == 1 and hub.dropped_total() == 34
    ok.close()
    await asyncio.wait_for(tasks[0], 1)


async def test_slow_client_sees_its_dropped_count_and_sequence_jump():
    hub = LiveHub(frame_rate_hz=25, max_queue=3, stall_timeout_s=5)
    got: list[bytes] = []
    gate = asyncio.Event()

    async def send(frame: bytes) -> None:
        await gate.wait()
        got.append(frame)

    client = hub.add_client(send)
    task = asyncio.ensure_future(client.run())
    hub.publish(_cols(0, 10))
    hub.tick()
    await asyncio.sleep(0)  # frame 1 is now in flight in the blocked send
    for i in range(1, 10):
        hub.publish(_cols(i, 10))
        hub.tick()
    await asyncio.sleep(0)
    gate.set()
    await asyncio.sleep(0.01)
    frames = [decode_frame(f) for f in got]
    # frame 1 was in flight; 2..10 arrived at a queue of 3: 6 dropped, 8, 9, 10 kept
    assert [f.sequence for f in frames] == [1, 8, 9, 10]
    assert [f.dropped for f in frames] == [0, 6, 6, 6]
    client.close()
    await asyncio.wait_for(task, 1)


async def test_framer_batches_published_samples_at_its_rate():
    hub = LiveHub(frame_rate_hz=50)
    frames: list[bytes] = []

    async def send(frame: bytes) -> None:
        frames.append(frame)

    client = hub.add_client(send)
    sender = asyncio.ensure_future(client.run())
    framer = asyncio.ensure_future(hub.run())
    for i in range(30):
        hub.publish(_cols(i * 0.01, 100))
        await asyncio.sleep(0.01)
    await asyncio.sleep(0.05)
    framer.cancel()
    client.close()
    await asyncio.gather(framer, sender, return_exceptions=True)
    decoded = [decode_frame(f) for f in frames]
    assert sum(f.n_samples for f in decoded) == 3000
    assert [f.sequence for f in decoded] == list(range(1, len(decoded) + 1))
    assert len(decoded) < 30  # several batches per frame: encoded at the frame rate, not per batch
    times = np.concatenate([f.columns["time_s"] for f in decoded])
    assert np.all(np.diff(times) > 0)


async def test_event_hub_numbers_replays_and_delivers_in_order():
    hub = EventHub(history=100)
    hub.bind_loop(asyncio.get_running_loop())
    hub.publish("test_state", id="a", status="queued")
    hub.publish("test_state", id="a", status="running")
    got: list[dict] = []
    closed = asyncio.Event()

    async def send(msg: dict) -> None:
        got.append(msg)

    serving = asyncio.ensure_future(hub.serve(send, closed.wait(), since=1))
    await asyncio.sleep(0.01)
    await asyncio.to_thread(lambda: [hub.publish("test_phase", id="a", phase=f"p{i}") for i in range(50)])
    await asyncio.sleep(0.05)
    closed.set()
    await asyncio.wait_for(serving, 1)
    assert got[0]["type"] == "hello" and got[0]["seq"] == 2
    seqs = [m["seq"] for m in got[1:]]
    assert seqs == list(range(2, 53))  # replay of 2, then 3..52 live, no gap, no duplicate


async def test_event_client_that_falls_behind_is_disconnected_not_silently_skipped():
    hub = EventHub(history=10, max_backlog=5)
    hub.bind_loop(asyncio.get_running_loop())
    blocked = asyncio.Event()
    got: list[dict] = []

    async def send(msg: dict) -> None:
        got.append(msg)
        if msg["type"] != "hello":
            await blocked.wait()  # this client stops consuming after the first event

    serving = asyncio.ensure_future(hub.serve(send, asyncio.Event().wait()))
    await asyncio.sleep(0.01)
    for i in range(20):
        hub.publish("test_phase", phase=f"p{i}")
    await asyncio.sleep(0.05)
    blocked.set()
    client = await asyncio.wait_for(serving, 1)
    assert client.overflowed  # the endpoint closes with 1013; the client resyncs with ?since=
    seqs = [m["seq"] for m in got[1:]]
    assert seqs == list(range(1, len(seqs) + 1)) and len(seqs) < 20  # an in-order prefix, never a gap
    assert [e["seq"] for e in hub.replay_after(12)] == list(range(13, 21))


def test_minmax_decimation_keeps_envelopes_and_real_torque_angle_pairs():
    rng = np.random.default_rng(4)
    n = 100_003  # not a multiple of the bucket count: the last bucket is short
    t = np.arange(n) * 1e-5
    torque = 500 * np.sin(2 * np.pi * t) + rng.normal(0, 0.3, n)
    angle = torque / 5 + 10 * np.sign(np.cos(2 * np.pi * t)) + rng.normal(0, 0.2, n)
    angle[70_001] = 99.0  # a spike the live view must not lose
    cols = {"time_s": t, "torque_nm": torque, "encoder_arcsec": 1.03 * angle, "angle_arcsec": angle}
    assert minmax_rows(cols, n) is None
    rows = minmax_rows(cols, 4000)
    assert len(rows) <= 4000 and np.all(np.diff(rows) > 0)  # whole samples, in time order
    assert {int(np.argmin(torque)), int(np.argmax(torque)), 70_001, int(np.argmin(angle))} <= set(rows.tolist())
    bucket = -(-n // 1000)  # 101 samples: 991 buckets, the last one short
    for b in (0, 517, 990):  # every bucket keeps its own extremes
        sl = slice(b * bucket, min(n, (b + 1) * bucket))
        assert sl.start + int(np.argmax(torque[sl])) in rows and sl.start + int(np.argmin(angle[sl])) in rows

    hub = LiveHub(frame_rate_hz=25, max_samples_per_frame=4000)
    hub.publish(cols)
    dec = decode_frame(hub.tick())
    assert dec.n_samples == len(rows) and hub.samples_decimated_total == n - len(rows)
    np.testing.assert_array_equal(dec.columns["angle_arcsec"], angle[rows].astype(np.float32))
    np.testing.assert_array_equal(dec.columns["encoder_arcsec"], cols["encoder_arcsec"][rows].astype(np.float32))
    hub.publish(_cols(5.0, 3000))  # a frame that fits passes untouched
    assert decode_frame(hub.tick()).n_samples == 3000 and hub.samples_decimated_total == n - len(rows)
    schema = schema_message(25, 4000)
    assert schema["max_samples_per_frame"] == 4000 and "min and max" in schema["decimation"]
    with pytest.raises(ValueError, match="max_samples_per_frame 3"):
        LiveHub(max_samples_per_frame=3)

"""The run's sample buffer: batches copied into column chunks, joined once (issue 10 item 6)."""

from __future__ import annotations

import numpy as np

from tcms_daq.acquisition.record import SampleBuffer
from tcms_daq.samples import Samples


def _batch(start: int, n: int, with_encoder: bool = True) -> Samples:
    t = np.arange(start, start + n, dtype=float)
    extra = {"encoder_arcsec": t * 3.0, "true_angle_arcsec": t * 4.0} if with_encoder else {}
    return Samples(t, t * 2.0, t * 0.5, extra)


def test_batches_across_chunk_boundaries_join_in_order():
    buf = SampleBuffer(chunk_samples=7)
    start = 0
    for n in (3, 5, 7, 20, 1):  # one batch larger than a chunk
        buf.append(_batch(start, n))
        start += n
    assert len(buf) == 36
    s = buf.to_samples()
    np.testing.assert_array_equal(s.time_s, np.arange(36.0))
    np.testing.assert_array_equal(s.torque_nm, np.arange(36.0) * 2.0)
    np.testing.assert_array_equal(s.extra["encoder_arcsec"], np.arange(36.0) * 3.0)


def test_appending_after_a_join_keeps_everything():
    buf = SampleBuffer(chunk_samples=4)
    buf.append(_batch(0, 10))
    first = buf.to_samples()
    buf.append(_batch(10, 6))
    again = buf.to_samples()
    np.testing.assert_array_equal(again.time_s, np.arange(16.0))
    np.testing.assert_array_equal(first.time_s, np.arange(10.0))  # the earlier result is not overwritten


def test_kept_columns_and_a_batch_missing_one():
    buf = SampleBuffer(columns=("encoder_arcsec",), chunk_samples=8)
    buf.append(_batch(0, 4))
    buf.append(_batch(4, 3, with_encoder=False))
    s = buf.to_samples()
    assert set(s.extra) == {"encoder_arcsec"}  # true_angle_arcsec not kept
    assert np.isnan(s.extra["encoder_arcsec"][4:]).all()
    np.testing.assert_array_equal(s.extra["encoder_arcsec"][:4], np.arange(4.0) * 3.0)


def test_an_empty_buffer_gives_empty_samples():
    assert len(SampleBuffer().to_samples()) == 0

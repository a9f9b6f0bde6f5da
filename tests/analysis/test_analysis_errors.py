"""Data that cannot be evaluated raise one-line DataFormatError / EvaluationError."""

from __future__ import annotations

import numpy as np
import pytest

from tcms_daq.analysis import evaluate
from tcms_daq.errors import DataFormatError, EvaluationError


def run(t, torque, angle, **kw):
    kw.setdefault("rated_torque_nm", 1078.0)
    return evaluate(t, torque, angle, **kw)


def one_line(excinfo) -> str:
    msg = str(excinfo.value)
    assert msg and "\n" not in msg
    return msg


def test_too_few_samples():
    with pytest.raises(DataFormatError) as e:
        run(np.arange(5.0), np.zeros(5), np.zeros(5))
    assert "too few samples: 5" in one_line(e)


def test_length_mismatch():
    with pytest.raises(DataFormatError) as e:
        run(np.arange(50.0), np.zeros(50), np.zeros(49))
    assert "lengths differ" in one_line(e)


@pytest.mark.parametrize("column", ["time_s", "torque_nm", "angle_arcsec"])
def test_nan(rv110e_record, column):
    cols = {"time_s": rv110e_record.time_s.copy(), "torque_nm": rv110e_record.torque_nm.copy(),
            "angle_arcsec": rv110e_record.angle_arcsec.copy()}
    cols[column][1234] = np.nan
    with pytest.raises(DataFormatError) as e:
        run(cols["time_s"], cols["torque_nm"], cols["angle_arcsec"])
    msg = one_line(e)
    assert column in msg and "1234" in msg


def test_non_monotonic_time(rv110e_record):
    t = rv110e_record.time_s.copy()
    t[500] = t[499]
    with pytest.raises(DataFormatError) as e:
        run(t, rv110e_record.torque_nm, rv110e_record.angle_arcsec)
    assert "not strictly increasing at sample 500" in one_line(e)


def test_no_full_loop_single_ramp():
    t = np.linspace(0.0, 20.0, 2001)
    torque = np.interp(t, [0, 10, 20], [0, 1078, 0])
    with pytest.raises(EvaluationError) as e:
        run(t, torque, torque * 0.2)
    assert "no full hysteresis loop" in one_line(e)


def test_no_full_loop_half_cycle(synth, loop_model):
    rec = synth(loop_model(), loops=1, conditioning_loops=0)
    cut = rec.time_s < rec.time_s[0] + 3.0 * 1078 / 100.0 * 1.5  # 0 → −T → +T (one full branch only)
    with pytest.raises(EvaluationError) as e:
        run(rec.time_s[cut], rec.torque_nm[cut], rec.angle_arcsec[cut])
    assert "no full hysteresis loop" in one_line(e)


def test_zero_torque():
    with pytest.raises(EvaluationError) as e:
        run(np.arange(100.0), np.zeros(100), np.zeros(100))
    assert "zero" in one_line(e)


def test_torque_never_reaches_the_interval(rv110e_record):
    with pytest.raises(EvaluationError) as e:
        run(rv110e_record.time_s, rv110e_record.torque_nm, rv110e_record.angle_arcsec, test_torque_nm=2500.0)
    assert "never reaches the evaluation interval" in one_line(e)


def test_lost_motion_level_beyond_the_reached_torque(synth, loop_model):
    rec = synth(loop_model(test_torque_nm=100.0))
    with pytest.raises(EvaluationError) as e:
        run(rec.time_s, rec.torque_nm, rec.angle_arcsec, rated_torque_nm=1078.0, lost_motion_pct=10.0)
    assert "never reaches" in one_line(e)


def test_skipping_every_loop(rv110e_record):
    with pytest.raises(EvaluationError) as e:
        run(rv110e_record.time_s, rv110e_record.torque_nm, rv110e_record.angle_arcsec, skip_loops=4)
    assert "4 full loop(s) and 4 are skipped" in one_line(e)


@pytest.mark.parametrize(
    "kwargs, text",
    [
        ({"rated_torque_nm": 0.0}, "rated torque"),
        ({"rated_torque_nm": float("nan")}, "rated torque"),
        ({"test_torque_nm": -5.0}, "test torque"),
        ({"lost_motion_pct": 0.0}, "lost-motion"),
        ({"rigidity_interval": (0.8, 0.5)}, "rigidity interval"),
        ({"rigidity_interval": (0.5, 1.2)}, "rigidity interval"),
        ({"skip_loops": -1}, "skip_loops"),
    ],
)
def test_bad_parameters(rv110e_record, kwargs, text):
    with pytest.raises(EvaluationError) as e:
        run(rv110e_record.time_s, rv110e_record.torque_nm, rv110e_record.angle_arcsec, **kwargs)
    assert text in one_line(e)


def test_decreasing_angle_is_reported(rv110e_record):
    with pytest.raises(EvaluationError) as e:
        run(rv110e_record.time_s, rv110e_record.torque_nm, -rv110e_record.angle_arcsec)
    assert "angle does not increase with torque" in one_line(e)


def test_noise_only_record():
    rng = np.random.default_rng(0)
    t = np.arange(5000) * 0.002
    with pytest.raises(EvaluationError) as e:
        run(t, 0.5 * rng.standard_normal(t.size), 0.2 * rng.standard_normal(t.size))
    assert "within its noise" in one_line(e)

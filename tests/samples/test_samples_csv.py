"""Canonical CSV round trip and the one-line errors of the reader."""

import numpy as np
import pytest

from tcms_daq.errors import DataFormatError
from tcms_daq.samples import Samples, read_csv, write_csv


def test_round_trip_is_exact_and_keeps_extra_columns(tmp_path):
    rng = np.random.default_rng(3)
    s = Samples(np.arange(5) * 0.01, rng.normal(size=5) * 100, rng.normal(size=5), {"encoder_arcsec": rng.normal(size=5)})
    path = tmp_path / "x.csv"
    write_csv(path, s)
    back = read_csv(path)
    for name, col in s.columns().items():
        np.testing.assert_array_equal(back.columns()[name], col)


@pytest.mark.parametrize(
    "text, fragment",
    [
        ("time_s,torque_nm\n0,1\n", "missing column 'angle_arcsec'"),
        ("time_s,torque_nm,angle_arcsec\n0,1,x\n", "non-numeric value 'x' in column 'angle_arcsec' at line 2"),
        ("time_s,torque_nm,angle_arcsec\n0,1\n", "line 2 has 2 fields"),
        ("", "empty file"),
        ("time_s,torque_nm,angle_arcsec\n0,inf,1\n", "non-finite value in column 'torque_nm'"),
    ],
)
def test_reader_names_the_problem(tmp_path, text, fragment):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(DataFormatError) as info:
        read_csv(path)
    assert fragment in str(info.value)
    assert "\n" not in str(info.value)


def test_missing_file(tmp_path):
    with pytest.raises(DataFormatError, match="no such file"):
        read_csv(tmp_path / "nope.csv")


def test_length_mismatch_is_rejected():
    with pytest.raises(DataFormatError, match="column lengths differ"):
        Samples([0, 1], [0], [0, 1])

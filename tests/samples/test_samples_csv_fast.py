"""Large CSV files are read by Arrow's reader with the same columns as the Python reader, and anything that is not a
well-formed numeric file still gets the Python reader's one-line message."""

from __future__ import annotations

import numpy as np
import pytest

from tcms_daq.errors import DataFormatError
from tcms_daq.samples import _arrow_columns, parse_csv_text, read_csv_columns


def _big_text(n: int = 60_000) -> str:
    rng = np.random.default_rng(3)
    rows = np.column_stack((np.arange(n) * 1e-3, rng.normal(0, 300, n), rng.normal(0, 200, n)))
    return "time_s,torque_nm,angle_arcsec,note\n" + "\n".join(
        f"{float(t)!r},{float(q)!r},{float(a)!r},x" for t, q, a in rows) + "\n"


def test_a_large_file_reads_the_same_as_the_python_reader(tmp_path):
    text = _big_text()
    assert len(text) > 1_000_000 and _arrow_columns(text, ("time_s",)) is not None  # the fast path reads it
    path = tmp_path / "big.csv"
    path.write_text(text, encoding="utf-8")
    fast = read_csv_columns(path)
    slow = parse_csv_text(text)
    assert set(fast) == set(slow) == {"time_s", "torque_nm", "angle_arcsec"}
    for name in fast:
        np.testing.assert_array_equal(fast[name], slow[name])


def test_a_bad_value_in_a_large_file_is_reported_by_line(tmp_path):
    lines = _big_text().splitlines()
    lines[40_000] = lines[40_000].replace(",", ",oops", 1)
    path = tmp_path / "bad.csv"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    with pytest.raises(DataFormatError, match="line 40001"):
        read_csv_columns(path)

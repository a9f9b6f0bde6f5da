"""iso_many (an SPC chart's 10 000 creation times at once) writes each time as iso does, character for character."""

from __future__ import annotations

import numpy as np
import pytest

from tcms_daq.store.base import iso, iso_many


def test_iso_many_is_iso_of_each_time():
    rng = np.random.default_rng(27)
    whole = np.floor(rng.uniform(1.7e9, 1.9e9, 5000))
    edges = whole + rng.choice([0.9999995, 0.0000005, 0.9999994999, 0.0005, 0.0015, 0.9995, 0.999999999], whole.size)
    times = np.concatenate([rng.uniform(1.7e9, 1.9e9, 20_000), rng.uniform(-1e9, 1e9, 2000), edges,
                            [0.0, 1.0, -0.5, -1.0000005, 1.7e9 + 0.0005]])
    assert iso_many(times) == [iso(t) for t in times.tolist()]
    assert iso_many([]) == []
    with pytest.raises(ValueError, match="finite"):
        iso_many([1.0, float("nan")])

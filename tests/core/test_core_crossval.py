"""The one fold maker: contiguous blocks and leave-one-group-out folds."""

from __future__ import annotations

import numpy as np
import pytest

from tcms_daq.crossval import contiguous_blocks, leave_one_group_out


def test_contiguous_blocks_are_ordered_and_nearly_equal():
    labels = contiguous_blocks(35, 6)
    assert np.all(np.diff(labels) >= 0) and set(labels) == set(range(6))
    sizes = np.bincount(labels)
    assert sizes.max() - sizes.min() <= 1 and sizes.sum() == 35
    with pytest.raises(ValueError):
        contiguous_blocks(10, 0)


def test_every_row_is_tested_exactly_once_and_never_trained_on_in_its_fold():
    rows = np.array([3, 5, 7, 9, 11, 13])
    folds = leave_one_group_out(rows, np.array([0, 0, 1, 1, 2, 2]))
    tested = np.concatenate([test for _, test in folds])
    assert sorted(tested.tolist()) == rows.tolist()
    for train, test in folds:
        assert not set(train) & set(test) and len(train) + len(test) == len(rows)
    with pytest.raises(ValueError, match="5 labels for 6 rows"):
        leave_one_group_out(rows, np.zeros(5))

"""Cross-validation folds: the one fold maker of the calibration (``compensation.calibration``) and the
discrepancy workflow (``discrepancy.selection``). Pure numpy."""

from __future__ import annotations

import numpy as np


def contiguous_blocks(n: int, n_blocks: int) -> np.ndarray:
    """Group labels 0 … n_blocks−1 of ``n`` consecutive rows in contiguous blocks of (nearly) equal size: row i is
    in block ⌊i·n_blocks/n⌋. For series, where neighbouring rows are correlated and leave-one-out is optimistic."""
    if n_blocks < 1:
        raise ValueError(f"n_blocks must be >= 1 (got {n_blocks})")
    return (np.arange(n) * n_blocks // max(n, 1)).astype(int)


def leave_one_group_out(rows: np.ndarray, labels: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """(train rows, test rows) per distinct label, in label order; ``labels[i]`` is the group of ``rows[i]``."""
    if len(labels) != len(rows):
        raise ValueError(f"{len(labels)} labels for {len(rows)} rows")
    return [(rows[labels != lab], rows[labels == lab]) for lab in np.unique(labels)]

"""Robust estimates of the white-noise level of a sampled signal.

Used to size the local fitting windows of the branch interpolation: noiseless data get exact linear
interpolation between the two bracketing samples, noisy data a local least-squares line over enough samples.
"""

from __future__ import annotations

import math

import numpy as np

_MAD_TO_STD = 1.482602218505602  # std of a normal distribution per median absolute deviation
MAX_POINTS = 200_000
_MIN_ZERO_STEP_FRACTION = 0.05  # share of repeated values above which a signal is treated as quantised


def white_noise_std(x: np.ndarray) -> float:
    """Std of the sample-to-sample noise of ``x`` (same unit as ``x``).

    The second difference of a smooth signal sampled densely is ~0, of white noise with std σ it has std
    σ·√6; the median absolute deviation makes the estimate blind to the few turning points and steps of a
    test profile. A quantised signal (many repeated values, nonzero steps of one size q) gets the floor
    q/√12 of its rounding error.
    """
    x = np.asarray(x, dtype=float)
    if x.size < 3:
        return 0.0
    # Medians of a regular subset of at most MAX_POINTS differences: the same estimate, a fraction of the time.
    stride = max(1, math.ceil((x.size - 2) / MAX_POINTS))
    d2 = np.diff(x, 2)[::stride]
    sigma = _MAD_TO_STD * float(np.median(np.abs(d2 - np.median(d2)))) / math.sqrt(6.0)
    d1 = np.abs(np.diff(x))[::stride]
    nonzero = d1[d1 > 0.0]
    if nonzero.size and nonzero.size < (1.0 - _MIN_ZERO_STEP_FRACTION) * d1.size:
        q = float(nonzero.min())
        if float(np.median(nonzero)) <= 1.5 * q:
            sigma = math.hypot(sigma, q / math.sqrt(12.0))
    return sigma

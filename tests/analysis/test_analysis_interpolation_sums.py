"""The local fits' normal equations are summed exactly as ``np.einsum`` summed them (bit for bit), so the faster
sum changes no result (issue 27 item 7)."""

from __future__ import annotations

import numpy as np
import pytest

from tcms_daq.analysis.interpolation import _products_summed


@pytest.mark.parametrize("levels", [1, 3, 208, 401])
@pytest.mark.parametrize("window", [2, 3, 8, 9, 57, 129, 2000])
@pytest.mark.parametrize("degree", [1, 2])
def test_products_summed_equals_einsum_bit_for_bit(levels, window, degree):
    rng = np.random.default_rng(levels * 10_000 + window * 10 + degree)
    u = rng.uniform(-1.0, 1.0, (levels, window))
    weight = (rng.uniform(size=(levels, window)) > 0.2).astype(float)
    values = rng.normal(size=(levels, window, 2)) * np.array([800.0, 3000.0])  # torque N·m, angle arcsec
    design = np.stack([u**k for k in range(degree + 1)], axis=2)
    weighted = design * weight[:, :, None]
    for other, spec in ((design, "lik,lij->lkj"), (values, "lik,lic->lkc")):
        got = _products_summed(weighted, other)
        want = np.einsum(spec, weighted, other)
        assert got.shape == want.shape
        assert np.array_equal(got, want), f"differs by {np.max(np.abs(got - want)):.3g} at {levels}×{window}"

"""The named parameters' uncertainties: the jackknife's degrees of freedom and the expanded U it gives.

The delete-one-group jackknife has g − 1 degrees of freedom; with the few loops of a test the error over its u
follows Student's t, not a normal distribution, so ±2u covers well under 95 % (the trials' and the independent
generator's coverage: ``python -m tcms_daq.sim.coverage``, docs/discrepancy.md). U = k·u with k = t₉₅(g − 1) does.
"""

from __future__ import annotations

import numpy as np
import pytest

from tcms_daq.discrepancy.design import build_design
from tcms_daq.discrepancy.model_file import DiscrepancyModel, ModelTerm, parse_model
from tcms_daq.discrepancy.selection import Columns, fit_model
from tcms_daq.discrepancy.workflow import EXPANDED_COVERAGE, coverage_factor, jackknife_uncertainties
from tcms_daq.samples import Samples

HIDDEN_RATIO = 0.01


def _z_scores(loops: int, runs: int) -> tuple[np.ndarray, int]:
    """|error|/u of a hidden 1 % scale error over ``runs`` seeds: ±500 N·m triangle loops, a linear model, noise
    correlated along the trace (AR(1), ρ = 0.9: neighbouring samples are not independent, loops nearly are)."""
    knots = [0.0, -500.0] + [500.0, -500.0] * loops + [0.0]
    torque = np.concatenate([np.linspace(a, b, 60, endpoint=False) for a, b in zip(knots[:-1], knots[1:], strict=True)])
    time_s = np.arange(len(torque)) * 0.1
    simulated = torque / 5.0
    z, groups = [], set()
    for seed in range(runs):
        rng = np.random.default_rng([seed, 24])
        white = rng.normal(0.0, 0.2, len(torque))
        noise = np.zeros(len(torque))
        for i in range(1, len(torque)):
            noise[i] = 0.9 * noise[i - 1] + white[i]
        data = build_design(Samples(time_s, torque, simulated * (1 + HIDDEN_RATIO) + noise),
                            Samples(time_s, torque, simulated))
        cols, y = Columns(data), data.residual_arcsec
        params = fit_model(cols, y, np.arange(len(y)), ["scale_error"]).parameters()
        u = jackknife_uncertainties(cols, y, data.groups, ["scale_error"], params)["scale_error"]["ratio"]
        z.append(abs(params["scale_error"]["ratio"] - HIDDEN_RATIO) / u)
        groups.add(len(np.unique(data.groups)))
    assert len(groups) == 1
    return np.array(z), groups.pop()


def test_expanded_uncertainty_covers_about_95_percent_where_2u_does_not():
    z, g = _z_scores(loops=3, runs=400)
    k = coverage_factor(g - 1)
    assert g == 5 and k == pytest.approx(2.776, abs=0.001)  # t₉₅ for 4 degrees of freedom
    # ±2u, the old reading of "U", covers 86 % of these 400 runs; U = k·u 93 %
    assert np.mean(z <= 2.0) < 0.89
    assert np.mean(z <= k) >= 0.91


def test_model_file_carries_the_degrees_of_freedom_and_u():
    term = ModelTerm("backlash", {"backlash_arcsec": 2.01}, [], {"backlash_arcsec": 0.004}, 7)
    text = DiscrepancyModel(terms=[term]).to_toml()
    back = parse_model(text).terms[0]
    assert back.uncertainty_dof == 7 and back.standard_uncertainty == {"backlash_arcsec": 0.004}
    k = coverage_factor(7, EXPANDED_COVERAGE)
    assert back.expanded_uncertainty["backlash_arcsec"] == pytest.approx(k * 0.004)
    assert "[terms.expanded_uncertainty]" in text and "coverage_factor = 2.365" in text
    # a file without degrees of freedom (written before them) still reads, with u and no U
    old = parse_model(text.replace("uncertainty_dof = 7\n", "")).terms[0]
    assert old.uncertainty_dof is None and old.expanded_uncertainty == {} and old.standard_uncertainty

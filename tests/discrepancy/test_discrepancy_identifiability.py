"""Identifiability before naming: two terms that cancel (two near-equal periods, a scale error against shaft
torsion) are never both reported as identified; what they fitted is either one simpler name or an alias group
with the experiment that separates it, and the verdict is never ``explained`` on such a pair.

The hidden shapes are added to a null run of the simulated bench by formulas written here (two sinusoids in the
angle at near-equal periods with opposite signs; s·θ − c·T with c·T cancelling most of s·θ), not by the
catalogue's code."""

from __future__ import annotations

import numpy as np
import pytest

from tcms_daq.discrepancy import effects as fx
from tcms_daq.discrepancy.workflow import run_discrepancy
from tcms_daq.samples import Samples


def _with(pair, extra_arcsec):
    measured, simulated, _ = pair
    return Samples(measured.time_s, measured.torque_nm, measured.angle_arcsec + extra_arcsec), simulated


def _never_both(result, a: str, b: str) -> None:
    named = set(result.names)
    assert not {a, b} <= named, result.to_dict()
    in_model = {n for n, _ in result.model_terms}
    assert not {a, b} <= in_model, result.model_terms
    if not named & {a, b}:  # neither named: reported as an alias group with its separating experiment
        group = [g for g in result.aliases if set(g.names) == {a, b}]
        assert group and group[0].separating_experiment and not group[0].in_model, result.to_dict()
    assert result.verdict.verdict != "explained" or len(named & {a, b}) == 1


@pytest.mark.parametrize("ratio", [1.05, 1.10])
def test_two_near_equal_periods_are_never_both_identified(pair_cache, ratio):
    pair = pair_cache("null", 11)
    theta = pair[1].angle_arcsec
    beat = 1.5 * np.sin(2 * np.pi * theta / 72.0) - 1.5 * np.sin(2 * np.pi * theta / (72.0 * ratio) + 0.2)
    result = run_discrepancy(*_with(pair, beat))
    _never_both(result, fx.INTERPOLATION_ERROR, fx.PERIODIC_ERROR)
    assert result.verdict.verdict != "explained"


@pytest.mark.parametrize("share", [0.8, 0.95])
def test_scale_and_torsion_that_cancel_are_never_both_identified(pair_cache, share):
    pair = pair_cache("null", 12)
    theta, torque = pair[1].angle_arcsec, pair[1].torque_nm
    slope = np.polyfit(torque, theta, 1)[0]
    extra = 0.03 * theta - share * 0.03 * slope * torque  # 3 % scale, torsion cancelling `share` of it
    result = run_discrepancy(*_with(pair, extra))
    _never_both(result, fx.SCALE_ERROR, fx.TORSION_OFFSET)


def test_a_single_term_is_not_split_into_a_cancelling_pair(pair_cache):
    """The hidden-effect case itself keeps one name (the check costs nothing where nothing cancels)."""
    measured, simulated, _ = pair_cache(fx.INTERPOLATION_ERROR, 11)
    result = run_discrepancy(measured, simulated)
    assert result.names == [fx.INTERPOLATION_ERROR]
    assert result.verdict.verdict == "explained"

"""Issue 23 item 2 in a smaller sample: U on the validation families of benchmarks/coverage (reducers, friction laws,
lost-motion zones, profiles and noise written from physics, not from the evaluation), through what
``tcms analyze --uncertainty chain.toml`` does. Per family and quantity the coverage is within a binomial band of
95 % and |bias| < U/3; the full figures (200 runs per family) are ``python -m benchmarks.coverage``."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import binom

from benchmarks.coverage import declared_chain, run_family
from benchmarks.coverage.families import FAMILIES

RUNS = 12
NO_HOLD_RUNS = 30
# fewer covered runs than this has a probability below 1 % when the coverage is 95 %
LOW = int(binom.ppf(0.01, RUNS, 0.95))


@pytest.fixture(scope="module")
def chain():
    return declared_chain()


# known failures (issue 23 left open): the rigidity on the play-operator (Prandtl–Ishlinskii) families keeps a bias
# in noise that the noise bootstrap does not see (+0.1 % continuous at 1 kHz, 0 to 3× noise; −0.19 % on the 1 kHz
# staircase at 3×): the local fits' windows, widened by the noise, straddle the operator's corners
NOT_YET = {"rv-play-hard-1khz", "hd-play-soft-stepped-1khz"}
KNOWN_FAILURE = pytest.mark.xfail(strict=True, reason="rigidity biased in noise on this play-operator family")


@pytest.mark.parametrize("family", [pytest.param(f, marks=KNOWN_FAILURE) if f.name in NOT_YET else f
                                    for f in FAMILIES], ids=[f.name for f in FAMILIES])
def test_u_covers_the_truth_on_every_validation_family(family, chain):
    result = run_family(family, RUNS, seed=1, chain=chain)
    assert not result.failed, result.failed
    for q, s in result.summary().items():
        covered = round(s["coverage"] * s["runs"])
        assert covered >= LOW, (family.name, q, s)
        assert abs(s["bias_over_U"]) < 1 / 3, (family.name, q, s)


@pytest.mark.parametrize("name", ["rv-dahl-soft-50hz", pytest.param("rv-play-hard-1khz", marks=KNOWN_FAILURE)])
def test_without_tip_holds_rigidity_and_lost_motion_are_within_u_in_93_percent(name, chain):
    family = next(f for f in FAMILIES if f.name == name)
    result = run_family(family, NO_HOLD_RUNS, seed=2, chain=chain)
    assert family.tip_hold_s == 0.0 and not result.failed
    for q in ("rigidity_nm_per_arcmin", "lost_motion_arcsec"):
        err, big_u = np.abs(result.stats[q].errors), np.asarray(result.stats[q].expanded)
        assert np.mean(err <= big_u) >= 0.93, (name, q, np.mean(err <= big_u))


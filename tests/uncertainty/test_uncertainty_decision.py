"""ISO 14253-1 decisions in Limits.judge: simple acceptance, and guard bands of U (pass / fail / undecided)."""

import pytest

from tcms_daq.analysis import Limits
from tcms_daq.analysis.rounding import round_to_uncertainty, with_uncertainty
from tcms_daq.errors import EvaluationError

LIMITS = Limits(rigidity_min_nm_per_arcmin=235.0, backlash_max_arcsec=60.0)


def values(rigidity, backlash):
    return {"rigidity_nm_per_arcmin": rigidity, "backlash_arcsec": backlash, "lost_motion_arcsec": 10.0}


@pytest.mark.parametrize("backlash, U, simple, guarded", [
    (50.0, 2.0, "pass", "pass"),       # inside by more than U
    (59.0, 2.0, "pass", "undecided"),  # inside, but by less than U
    (61.0, 2.0, "fail", "undecided"),  # outside, but by less than U
    (63.0, 2.0, "fail", "fail"),       # outside by more than U
])
def test_guard_bands(backlash, U, simple, guarded):
    expanded = {"backlash_arcsec": U, "rigidity_nm_per_arcmin": 1.0}
    s = LIMITS.judge(values(300.0, backlash), expanded, "simple")
    g = LIMITS.judge(values(300.0, backlash), expanded, "guarded")
    assert s["checks"]["backlash_max_arcsec"]["decision"] == simple and s["decision"] == simple
    assert g["checks"]["backlash_max_arcsec"]["decision"] == guarded and g["decision"] == guarded
    assert g["checks"]["backlash_max_arcsec"]["guard_band"] == U and s["checks"]["backlash_max_arcsec"]["guard_band"] == 0
    assert g["passed"] is (guarded == "pass") and s["passed"] is (simple == "pass")


def test_lower_limit_and_overall_decision():
    g = LIMITS.judge(values(236.0, 10.0), {"rigidity_nm_per_arcmin": 2.0, "backlash_arcsec": 0.5}, "guarded")
    assert g["checks"]["rigidity_min_nm_per_arcmin"]["decision"] == "undecided"
    assert g["decision"] == "undecided" and g["passed"] is False
    f = LIMITS.judge(values(230.0, 10.0), {"rigidity_nm_per_arcmin": 2.0, "backlash_arcsec": 0.5}, "guarded")
    assert f["decision"] == "fail"


def test_without_u_the_guard_band_is_zero_and_says_so():
    g = LIMITS.judge(values(300.0, 59.9), None, "guarded")
    assert g["decision"] == "pass" and g["checks"]["backlash_max_arcsec"]["U"] is None
    with pytest.raises(EvaluationError, match="decision rule"):
        LIMITS.judge(values(300.0, 10.0), None, "lenient")


@pytest.mark.parametrize("value, U, shown", [
    (303.92211, 0.0708006, ("303.922", "0.071")),
    (293.9567, 2.34, ("294.0", "2.3")),
    (25.19, 0.0996, ("25.19", "0.10")),
    (110234.0, 2345.0, ("110200", "2300")),
])
def test_two_significant_digits_of_u(value, U, shown):
    assert round_to_uncertainty(value, U) == shown


def test_with_uncertainty_text():
    assert with_uncertainty(303.92211, {"U": 0.0708006, "k": 2.05, "unit": "N·m/arcmin"}) == \
        "303.922 ± 0.071 N·m/arcmin (k = 2.05)"
    assert with_uncertainty(25.0, None, "arcsec") == "25″ (U not stated)"

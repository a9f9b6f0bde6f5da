"""Where one run cannot identify an effect, the result names the run to add as a request the service accepts."""

from __future__ import annotations

import pytest

from tcms_daq.discrepancy import catalogue as cat
from tcms_daq.discrepancy import effects as fx
from tcms_daq.discrepancy.stored import RATE_FACTOR, TIP_DWELL_S, separating_request
from tcms_daq.service import schemas

STORED = {"reducer": "RV-110E", "max_torque_nm": 800.0, "cycles": 3, "rate_nm_per_s": 300.0, "profile": "continuous",
          "serial_number": "SN-1", "user": "alice", "plan": {"name": "p", "version": 1}}


def test_each_pair_a_request_can_separate_has_its_kind():
    assert cat.separating_run([fx.TIME_SKEW, fx.BACKLASH]) == fx.SECOND_RATE
    assert cat.separating_run([fx.BACKLASH, fx.NONLINEAR_STIFFNESS]) == fx.TIP_HOLDS
    assert cat.separating_run([fx.TIME_SKEW, fx.THERMAL_DRIFT]) == fx.SECOND_RATE  # by member: a skew
    assert cat.separating_run([fx.SCALE_ERROR, fx.TORSION_OFFSET]) is None  # needs another lever arm, not a request


def test_a_second_rate_keeps_the_test_and_adds_a_rate():
    body = separating_request(fx.SECOND_RATE, STORED, reducer="RV-110E", max_torque_nm=800.0, rate_nm_per_s=300.0,
                              max_rate_nm_per_s=2000.0)
    assert body == {"reducer": "RV-110E", "max_torque_nm": 800.0, "cycles": 3, "serial_number": "SN-1",
                    "profile": "continuous", "rates": [300.0, 300.0 * RATE_FACTOR]}
    schemas.TestRequest.model_validate(body)  # the service accepts it (the stored user and plan are not request fields)
    slow = separating_request(fx.SECOND_RATE, STORED, reducer="RV-110E", max_torque_nm=800.0, rate_nm_per_s=900.0,
                              max_rate_nm_per_s=2000.0)
    assert slow is not None and slow["rates"] == [900.0, 300.0]  # the bench cannot go 3× faster: 3× slower
    two = {**STORED, "rates": [300.0, 900.0]}
    assert separating_request(fx.SECOND_RATE, two, reducer="RV-110E", max_torque_nm=800.0, rate_nm_per_s=300.0,
                              max_rate_nm_per_s=2000.0) is None  # it had two rates already


def test_tip_holds_are_a_stepped_profile_that_dwells():
    body = separating_request(fx.TIP_HOLDS, STORED, reducer="RV-110E", max_torque_nm=800.0, rate_nm_per_s=300.0,
                              max_rate_nm_per_s=2000.0)
    assert body is not None and body["profile"] == "stepped" and body["dwell_s"] == TIP_DWELL_S
    assert 800.0 / body["step_nm"] == pytest.approx(round(800.0 / body["step_nm"]))  # a step lands on the tip
    schemas.TestRequest.model_validate(body)

"""plan_from_request: the one path from a test request to a plan, with its limit policy (bench limit, the
reducer's rated torque, the bench's bounds) checked there."""

from __future__ import annotations

import pytest
from pydantic import ValidationError

from tcms_daq.config import load_bench_config, load_reducers_for
from tcms_daq.procedure.plan import REDUCER_TORQUE_HEADROOM, PlanRejected, PlanRequest, plan_from_request


@pytest.fixture(scope="module")
def cfg():
    return load_bench_config()


@pytest.fixture(scope="module")
def catalogue(cfg):
    return load_reducers_for(cfg)


def test_defaults_come_from_the_procedure_and_the_reducer(cfg, catalogue):
    plan = plan_from_request(PlanRequest(reducer="RV-110E"), cfg, catalogue)
    rated = catalogue["RV-110E"].rated_torque_nm
    assert plan.plan.kind == "single" and plan.profile.test_torque_nm == rated
    assert plan.profile.cycles == cfg.procedure.cycles
    assert plan.profile.conditioning_loops == cfg.procedure.conditioning_loops
    assert plan.decision_rule == cfg.bench.decision_rule
    assert plan.reducer_torque_limit_nm == pytest.approx(REDUCER_TORQUE_HEADROOM * rated)


def test_request_fields_override_the_defaults(cfg, catalogue):
    request = PlanRequest(reducer="rv-110e", max_torque_nm=500, profile="stepped", step_nm=100, dwell_s=0.5,
                          cycles=2, decision_rule="simple")
    plan = plan_from_request(request, cfg, catalogue)
    p = plan.profile
    assert (plan.reducer.name, p.kind, p.test_torque_nm, p.step_nm, p.dwell_s, p.cycles) == (
        "RV-110E", "stepped", 500.0, 100.0, 0.5, 2)
    assert plan.decision_rule == "simple"
    assert plan.summary()["segments"] == len(p.segments)


def test_a_torque_above_the_rated_torque_is_refused(cfg, catalogue):
    rated = catalogue["RV-110E"].rated_torque_nm
    with pytest.raises(PlanRejected, match=f"exceeds the rated torque {rated:g} N·m of RV-110E"):
        plan_from_request(PlanRequest(reducer="RV-110E", max_torque_nm=rated * 1.05), cfg, catalogue)
    plan_from_request(PlanRequest(reducer="RV-110E", max_torque_nm=rated), cfg, catalogue)  # at rated: runs


def test_a_torque_above_the_bench_limit_is_refused(cfg, catalogue):
    small = cfg.model_copy(update={"bench": cfg.bench.model_copy(update={"max_torque_nm": 300.0})})
    with pytest.raises(PlanRejected, match="exceeds the bench limit 300 N·m"):
        plan_from_request(PlanRequest(reducer="RV-110E", max_torque_nm=400), small, catalogue)


@pytest.mark.parametrize(("fields", "message"), [
    ({"reducer": "RV-999X"}, "unknown reducer 'RV-999X'"),
    ({"max_torque_nm": 0.5}, "below the bench's minimum test torque 1 N·m"),
    ({"rate_nm_per_s": 1e-3}, "below the bench's slowest rate"),
    ({"profile": "stepped", "step_nm": 1e-3}, "below the bench's smallest step"),
    ({"cycles": 100000}, "cycles: Input should be less than or equal to 1000"),
    ({"positions": 36, "cycles": 1000, "max_torque_nm": 500, "rate_nm_per_s": 2000}, "the bench takes at most"),
])
def test_out_of_bounds_requests_are_one_line_refusals(cfg, catalogue, fields, message):
    with pytest.raises(PlanRejected, match=message) as info:
        plan_from_request(PlanRequest(**{"reducer": "RV-110E", **fields}), cfg, catalogue)
    assert "\n" not in str(info.value)


def test_positions_and_rates_make_plans_of_stages(cfg, catalogue):
    plan = plan_from_request(PlanRequest(reducer="RV-110E", max_torque_nm=500, positions=3), cfg, catalogue)
    assert plan.plan.kind == "positions" and [s.position_deg for s in plan.plan.stages] == [0.0, 120.0, 240.0]
    plan = plan_from_request(PlanRequest(reducer="RV-110E", max_torque_nm=500, rates=[50, 200]), cfg, catalogue)
    assert [s.rate_nm_per_s for s in plan.plan.stages] == [50.0, 200.0]
    assert plan.summary()["rates_nm_per_s"] == [50.0, 200.0]


def test_the_request_itself_is_validated():
    with pytest.raises(ValidationError, match="cannot be combined"):
        PlanRequest(reducer="RV-110E", positions=4, rates=[10.0])
    with pytest.raises(ValidationError):
        PlanRequest(reducer="RV-110E", max_torque_nm=float("inf"))

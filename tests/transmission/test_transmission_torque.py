"""Starting torque, no-load running torque and efficiency on the simulated RV-110E and HFUC-32-100: each result
within its U of the simulator's truth; the onset fit is what makes the starting torque unbiased (a threshold
crossing on the angle comes late); the torque reading's zero cancels in the no-load torque."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from tcms_daq.sim.station import (
    StationSensors,
    efficiency_profile,
    no_load_profile,
    record_speed_run,
    record_torque_run,
    starting_profile,
)
from tcms_daq.sim.transmission import (
    efficiency_truth,
    no_load_torque_truth,
    starting_torque_truth,
    unit_from_spec,
)

from tcms_daq.config.models import StationUncertainty, TorqueUncertainty
from tcms_daq.transmission.torque import (
    evaluate_efficiency,
    evaluate_no_load_torque,
    evaluate_starting_torque,
)
from tcms_daq.uncertainty.station import efficiency_budgets, no_load_torque_budgets, starting_torque_budgets

CHAIN = StationUncertainty(input_torque=TorqueUncertainty(u_rel=5e-4, u_zero_nm=0.002),
                           output_torque=TorqueUncertainty(u_rel=3e-4, u_zero_nm=0.05))
SENSORS = StationSensors(sample_rate_hz=1000.0, speed_ripple_pct=0.5, input_torque_noise_nm=0.002,
                         output_torque_noise_nm=0.3)
UNITS = ["RV-110E", "HFUC-32-100"]


def _within(budgets, truth):
    for name, expected in truth.items():
        b = budgets[name]
        assert abs(b.value - expected) <= b.expanded, (name, b.value, expected, b.expanded)


@pytest.mark.parametrize("name", UNITS)
def test_starting_torque_within_u(catalogue, name):
    spec = catalogue[name]
    unit = unit_from_spec(spec)
    breakaway = spec.sim.transmission.breakaway_torque_nm
    run = record_torque_run(unit, starting_profile(1.4 * breakaway, 0.25 * breakaway, ramps=3), SENSORS, seed=3)
    c = run.columns
    ev = evaluate_starting_torque(c["time_s"], c["input_torque_nm"], c["input_angle_arcsec"])
    budgets = starting_torque_budgets(c["time_s"], c["input_torque_nm"], c["input_angle_arcsec"], ev, CHAIN)
    forward, reverse = starting_torque_truth(unit, 1.0), starting_torque_truth(unit, -1.0)
    _within(budgets, {"forward_starting_torque_nm": forward, "reverse_starting_torque_nm": reverse,
                      "starting_torque_nm": max(forward, reverse)})
    assert len(ev.ramps) == 6 and not ev.warnings


def test_the_onset_fit_is_unbiased_where_a_threshold_crossing_is_late(catalogue):
    # without a drop from static to running friction the input starts slowly (θ ∝ (t − t0)³): a threshold on the
    # angle is crossed late, when the torque has risen; the fitted onset is not
    unit = unit_from_spec(catalogue["RV-110E"])
    unit = replace(unit, friction=replace(unit.friction, breakaway_nm=unit.friction.coulomb_nm))
    run = record_torque_run(unit, starting_profile(1.5, 0.2, ramps=2), SENSORS, seed=6)
    c = run.columns
    ev = evaluate_starting_torque(c["time_s"], c["input_torque_nm"], c["input_angle_arcsec"])
    truth = starting_torque_truth(unit, 1.0)
    angle, torque = c["input_angle_arcsec"], c["input_torque_nm"]
    late = torque[int(np.flatnonzero(np.abs(angle - angle[0]) > 3.0)[0])] - truth  # 2.5 counts of the encoder
    assert late > 0.003
    assert abs(ev.per_direction["forward"] - truth) < 0.2 * late


@pytest.mark.parametrize("name", UNITS)
def test_no_load_torque_within_u_and_the_zero_cancels(catalogue, name):
    unit = unit_from_spec(catalogue[name])
    speeds = [500.0, 1500.0, 3000.0]
    run = record_speed_run(unit, no_load_profile(speeds, dwell_s=1.5), SENSORS, seed=4)
    c = run.columns
    ev = evaluate_no_load_torque(c["time_s"], c["input_torque_nm"], c["input_angle_arcsec"], speeds_rpm=speeds)
    budgets = no_load_torque_budgets(c["time_s"], c["input_torque_nm"], c["input_angle_arcsec"], ev, CHAIN)
    truth = {}
    for n in speeds:
        fwd, rev = no_load_torque_truth(unit, n, 25.0), no_load_torque_truth(unit, -n, 25.0)
        truth.update({f"no_load_torque_nm@{n:g}rpm": 0.5 * (fwd + rev), f"forward_no_load_torque_nm@{n:g}rpm": fwd,
                      f"reverse_no_load_torque_nm@{n:g}rpm": rev})
    _within(budgets, truth)
    zero = next(line for line in budgets["no_load_torque_nm@1500rpm"].lines if line.source == "input torque zero")
    assert zero.contribution < 1e-9  # cancels between the directions …
    fwd_zero = next(line for line in budgets["forward_no_load_torque_nm@1500rpm"].lines
                    if line.source == "input torque zero")
    assert fwd_zero.sensitivity == pytest.approx(1.0)  # … not in one direction's


@pytest.mark.parametrize("name", UNITS)
def test_efficiency_within_u(catalogue, name):
    spec = catalogue[name]
    unit = unit_from_spec(spec)
    speed = spec.sim.transmission.rated_input_speed_rpm
    run = record_speed_run(unit, efficiency_profile(spec.rated_torque_nm, speed, dwell_s=2.0), SENSORS, seed=5)
    c = run.columns
    ev = evaluate_efficiency(c["time_s"], c["input_torque_nm"], c["input_angle_arcsec"], c["output_torque_nm"],
                             c["output_angle_arcsec"])
    budgets = efficiency_budgets(c["time_s"], c["input_torque_nm"], c["input_angle_arcsec"], c["output_torque_nm"],
                                 c["output_angle_arcsec"], ev, CHAIN)
    _within(budgets, {"forward_efficiency": efficiency_truth(unit, spec.rated_torque_nm, speed, 25.0),
                      "reverse_efficiency": efficiency_truth(unit, spec.rated_torque_nm, -speed, 25.0)})
    assert budgets["forward_efficiency"].value == pytest.approx(spec.sim.transmission.rated_efficiency_pct / 100,
                                                                 abs=budgets["forward_efficiency"].expanded)

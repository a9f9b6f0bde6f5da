"""The workflow on data the project did not make: a reducer written here from physics (a linear spring, a tanh
lost-motion zone and Dahl friction, driven by triangular torque loops), independent of ``sim/``.

Catalogue effects hidden in it are named with their values; effects outside the catalogue — a vibration in time,
a stiffness that changes mid-test, stick-slip jumps, a friction loop that widens loop by loop — are never called
``explained``; with nothing hidden, nothing is named.
"""

from __future__ import annotations

import numpy as np
import pytest

from tcms_daq.discrepancy.workflow import run_discrepancy
from tcms_daq.samples import samples_from_columns

COMPLIANCE_ARCSEC_PER_NM = 60.0 / 294.0  # an RV-110E-like 294 N·m/arcmin
NOISE_ARCSEC = 0.2


def torque_loops(test_torque_nm=1000.0, rate_nm_per_s=100.0, loops=3, rate_hz=50.0):
    """(time_s, torque_nm): 0 → −T, then ``loops`` times −T → +T → −T, then back to 0, at a constant rate."""
    corners = [0.0, -test_torque_nm] + [test_torque_nm, -test_torque_nm] * loops + [0.0]
    t, torque = [0.0], [0.0]
    for a, b in zip(corners, corners[1:], strict=False):
        n = int(abs(b - a) / rate_nm_per_s * rate_hz)
        torque.extend(np.linspace(a, b, n + 1)[1:])
        t.extend(t[-1] + np.arange(1, n + 1) / rate_hz)
    return np.array(t), np.array(torque)


def reducer_twist_arcsec(torque_nm, backlash_arcsec=6.0, zone_nm=15.0, friction_arcsec=4.0, dahl_nm=40.0,
                         width_growth_per_loop=0.0):
    """Spring + tanh lost-motion zone + Dahl friction whose state follows the torque increments."""
    d_torque = np.diff(torque_nm, prepend=torque_nm[0])
    state = np.zeros_like(torque_nm)
    for i in range(1, torque_nm.size):
        state[i] = state[i - 1] + (np.sign(d_torque[i]) - state[i - 1]) * (1 - np.exp(-abs(d_torque[i]) / dahl_nm))
    reversals = np.cumsum(np.abs(np.diff(np.sign(d_torque), prepend=0.0)) > 0) / 2.0
    width = friction_arcsec * (1.0 + width_growth_per_loop * reversals)
    return (COMPLIANCE_ARCSEC_PER_NM * torque_nm + 0.5 * backlash_arcsec * np.tanh(torque_nm / zone_nm)
            + 0.5 * width * state)


def pair(case: str, seed: int):
    rng = np.random.default_rng(seed)
    t, commanded = torque_loops()
    torque = commanded + 0.3 * rng.standard_normal(t.size)
    simulated = reducer_twist_arcsec(torque)
    measured = simulated.copy()
    if case == "thermal_drift":
        measured += 0.02 * t
    elif case == "vibration":
        measured += 0.8 * np.sin(2 * np.pi * 0.13 * t)
    elif case == "stiffness_change":
        measured += (t > t[-1] / 2) * 0.03 * COMPLIANCE_ARCSEC_PER_NM * torque
    elif case == "stick_slip":
        for jump_at_s in rng.uniform(t[0], t[-1], 3):
            measured += rng.choice([-1.0, 1.0]) * 1.2 * (t > jump_at_s)
    elif case == "wear_in":
        measured = reducer_twist_arcsec(torque, width_growth_per_loop=0.3)
    measured = measured + NOISE_ARCSEC * rng.standard_normal(t.size)
    cols = {"time_s": t, "torque_nm": torque}
    return (samples_from_columns({**cols, "angle_arcsec": measured}),
            samples_from_columns({**cols, "angle_arcsec": simulated}))


@pytest.mark.parametrize("seed", [1, 2])
def test_nothing_hidden_names_nothing(seed):
    result = run_discrepancy(*pair("null", seed), has_time=True).to_dict()
    assert result["verdict"] == "consistent" and result["effects"] == []


@pytest.mark.parametrize("seed", [1, 2])
def test_a_hidden_drift_is_named_with_its_rate(seed):
    result = run_discrepancy(*pair("thermal_drift", seed), has_time=True).to_dict()
    assert result["verdict"] == "explained"
    assert [e["name"] for e in result["effects"]] == ["thermal_drift"]
    assert result["effects"][0]["parameters"]["rate_arcsec_per_s"] == pytest.approx(0.02, rel=0.1)


@pytest.mark.parametrize("case", ["vibration", "stiffness_change", "stick_slip", "wear_in"])
def test_effects_outside_the_catalogue_are_never_explained(case):
    result = run_discrepancy(*pair(case, 1), has_time=True).to_dict()
    assert result["verdict"] in ("partially_explained", "unexplained"), (case, result["verdict"], result["effects"])
    assert result["unexplained"] is not None and result["unexplained"]["structured_rms_arcsec"] > 0.05
    if result["effects"]:
        assert result["names_provisional"]


def test_a_simulation_on_its_own_grid_driven_by_the_commanded_torque_still_names_the_drift():
    rng = np.random.default_rng(3)
    t, commanded = torque_loops()
    torque = commanded + 0.3 * rng.standard_normal(t.size)
    measured = reducer_twist_arcsec(torque) + 0.02 * t + NOISE_ARCSEC * rng.standard_normal(t.size)
    t_sim = np.arange(0.0, t[-1], 1 / 37.0)  # its own grid, driven by the command, its clock 0.5 s late
    torque_sim = np.interp(t_sim, t, commanded)
    simulated = samples_from_columns({"time_s": t_sim + 0.5, "torque_nm": torque_sim,
                                      "angle_arcsec": reducer_twist_arcsec(torque_sim)})
    result = run_discrepancy(samples_from_columns({"time_s": t, "torque_nm": torque, "angle_arcsec": measured}),
                             simulated, has_time=True).to_dict()
    assert [e["name"] for e in result["effects"]] == ["thermal_drift"]
    assert result["effects"][0]["parameters"]["rate_arcsec_per_s"] == pytest.approx(0.02, rel=0.1)

"""Pairs as users have them: a simulation on its own time grid, offset in time, or driven by the commanded
torque is put onto the measured rows (``tcms_daq.discrepancy.pairing``) and still names the hidden effect.

The simulated side here is written from the programme itself (the commanded ramps and dwells of
``sim.trials.TrialDesign``) and the catalogue reducer's forward model, on grids the measurement never had.
"""

from __future__ import annotations

import numpy as np
import pytest
from tcms_daq.sim.physics import twist_arcsec
from tcms_daq.sim.trials import TrialDesign, bench_run

from tcms_daq.discrepancy.pairing import estimate_time_offset_s, pair
from tcms_daq.discrepancy.workflow import run_discrepancy
from tcms_daq.errors import DataFormatError
from tcms_daq.samples import Samples

DRIFT = {"thermal_drift": {"rate_arcsec_per_s": 0.03}}


def commanded_profile(design: TrialDesign, rate_hz: float, start_s: float, hold_s: float = 0.05
                      ) -> tuple[np.ndarray, np.ndarray]:
    """(time s, commanded torque N·m) of the trial programme: ramps at each rate with holds at the targets."""
    knots_t, knots_T, t, level = [0.0], [0.0], 0.0, 0.0
    a = design.amplitude_nm
    targets = []
    for rate in design.rates_nm_per_s:
        targets.append((-a, rate))
        targets += [(a, rate), (-a, rate)] * design.loops_per_rate
    targets.append((0.0, design.rates_nm_per_s[0]))
    for target, rate in targets:
        t += abs(target - level) / rate
        knots_t.append(t)
        knots_T.append(target)
        t += hold_s
        knots_t.append(t)
        knots_T.append(target)
        level = target
    grid = np.arange(0.0, t, 1.0 / rate_hz)
    return grid + start_s, np.interp(grid, knots_t, knots_T)


@pytest.fixture(scope="module")
def drift_run():
    return bench_run(DRIFT, 31)


def test_simulation_on_its_own_grid_driven_by_the_commanded_torque_names_the_hidden_drift(drift_run):
    measured, physics = drift_run
    t_sim, torque_cmd = commanded_profile(TrialDesign(), rate_hz=37.0, start_s=measured.time_s[0] - 0.4)
    simulated = Samples(t_sim, torque_cmd, twist_arcsec(torque_cmd, physics)[0])
    result = run_discrepancy(measured, simulated)
    # the commanded torque, shifted by the estimated offset (0.4 s of clock + the loader's lag), matches the
    # measured one to its noise: compared on the time grid
    assert result.pairing.mode == "time_grid"
    assert 0.35 <= result.pairing.time_offset_s <= 0.41
    assert result.pairing.rows_used >= 0.9 * len(measured)
    assert result.names == ["thermal_drift"], result.to_dict()
    rate = result.effects[0].parameters["rate_arcsec_per_s"]
    assert rate == pytest.approx(0.03, rel=0.10)


def test_a_simulation_with_another_timing_is_compared_at_equal_torque(drift_run):
    """The simulation ran the programme with 0.2 s holds (the bench held 0.05 s): no time offset aligns the
    torque traces, so the loops are compared branch by branch at equal torque; the drift is still named."""
    measured, physics = drift_run
    t_sim, torque_cmd = commanded_profile(TrialDesign(), rate_hz=29.0, start_s=measured.time_s[0], hold_s=0.2)
    simulated = Samples(t_sim, torque_cmd, twist_arcsec(torque_cmd, physics)[0])
    result = run_discrepancy(measured, simulated)
    assert result.pairing.mode == "equal_torque"
    assert result.pairing.rows_used >= 0.9 * len(measured)
    assert result.names == ["thermal_drift"], result.to_dict()
    assert result.effects[0].parameters["rate_arcsec_per_s"] == pytest.approx(0.03, rel=0.10)


def test_simulation_on_its_own_time_grid_with_a_clock_offset(drift_run):
    """Driven by the measured torque, but sampled at 37 Hz and its clock 1 ms (then 0.7 s) off."""
    measured, physics = drift_run
    for offset_s in (1e-3, 0.7):
        t_sim = np.arange(measured.time_s[0], measured.time_s[-1], 1 / 37.0)
        torque = np.interp(t_sim, measured.time_s, measured.torque_nm)
        simulated = Samples(t_sim - offset_s, torque, twist_arcsec(torque, physics)[0])
        result = run_discrepancy(measured, simulated)
        assert result.pairing.mode == "time_grid", result.pairing
        assert result.pairing.time_offset_s == pytest.approx(offset_s, abs=2e-3)
        assert result.names == ["thermal_drift"], result.to_dict()


def test_time_offset_estimate_to_a_fraction_of_a_sample():
    t = np.arange(0, 60, 0.02)
    torque = 800 * np.sin(2 * np.pi * t / 7.0) + 300 * np.sin(2 * np.pi * t / 2.3)
    t_sim = np.arange(-3, 57, 0.03)
    torque_sim = 800 * np.sin(2 * np.pi * (t_sim + 0.137) / 7.0) + 300 * np.sin(2 * np.pi * (t_sim + 0.137) / 2.3)
    assert estimate_time_offset_s(t, torque, t_sim, torque_sim) == pytest.approx(0.137, abs=0.001)


def test_same_rows_are_used_as_they_are(drift_run):
    measured, physics = drift_run
    simulated = Samples(measured.time_s, measured.torque_nm, twist_arcsec(measured.torque_nm, physics)[0])
    m, s, how = pair(measured, simulated)
    assert how.mode == "same_rows" and m is measured and s is simulated


def test_what_cannot_be_compared_is_refused_with_the_reason(drift_run):
    measured, physics = drift_run
    far = Samples(measured.time_s[:-1] + 1e5, measured.torque_nm[:-1], measured.angle_arcsec[:-1])
    with pytest.raises(DataFormatError, match="no common time span"):
        pair(measured, far)
    one_leg = Samples(np.linspace(10, 11, 50), np.linspace(0, 10, 50), np.linspace(0, 2, 50))
    with pytest.raises(DataFormatError, match="covers only"):
        pair(measured, one_leg)
    backwards = Samples(measured.time_s[::-1].copy(), measured.torque_nm, measured.angle_arcsec)
    with pytest.raises(DataFormatError, match="goes backwards"):
        pair(measured, backwards)

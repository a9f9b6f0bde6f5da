"""The simulated unit turning (sim/transmission.py): batches give the same result as one piece; its transmission
error, starting torque, running torque and efficiency are the truth functions' exactly; [sim.transmission] is typed
and checked where the bench config is read; without it the bench is the stiffness bench."""

from __future__ import annotations

import math

import numpy as np
import pytest
from tcms_daq.sim.transmission import (
    UnitState,
    efficiency_truth,
    input_torque_nm,
    no_load_torque_truth,
    starting_torque_truth,
    transmission_error_arcsec,
    turn,
    turn_with_torque,
    unit_for_bench,
    unit_from_spec,
)

from tcms_daq.config import load_bench_config
from tcms_daq.errors import ConfigError
from tcms_daq.units import ARCSEC_PER_RAD, ARCSEC_PER_REV


@pytest.fixture(scope="module")
def rv(catalogue):
    return unit_from_spec(catalogue["RV-110E"])


def _speed_trace(n: int = 6000, rate_hz: float = 1000.0, rpm: float = 600.0):
    t = np.arange(1, n + 1) / rate_hz
    speed = rpm * np.minimum(1.0, t / 0.5) * np.where(t < 4.0, 1.0, -1.0)
    angle = np.cumsum(speed / 60.0 * ARCSEC_PER_REV / rate_hz)
    load = np.where(t < 4.0, -50.0, 50.0)
    return t, angle, load


def test_turning_in_batches_is_turning_in_one_piece(rv):
    t, angle, load = _speed_trace()
    whole, _ = turn(rv, UnitState(), t, angle, load, 30.0)
    state, parts = UnitState(), []
    for sl in np.array_split(np.arange(t.size), 7):
        part, state = turn(rv, state, t[sl], angle[sl], load[sl], 30.0)
        parts.append(part)
    for name in ("output_angle_arcsec", "input_torque_nm", "input_speed_rpm"):
        np.testing.assert_allclose(np.concatenate([getattr(p, name) for p in parts]), getattr(whole, name),
                                   rtol=0, atol=1e-9)
    torque = np.concatenate([np.linspace(0, 1.2, 3000), np.linspace(1.2, -1.3, 3000)])
    tt = np.arange(1, torque.size + 1) / 1000.0
    whole, _ = turn_with_torque(rv, UnitState(), tt, torque, 0.0)
    state, parts = UnitState(), []
    for sl in np.array_split(np.arange(tt.size), 5):
        part, state = turn_with_torque(rv, state, tt[sl], torque[sl], 0.0)
        parts.append(part)
    np.testing.assert_allclose(np.concatenate([p.input_angle_arcsec for p in parts]), whole.input_angle_arcsec,
                               rtol=1e-12, atol=1e-6)


def test_output_angle_is_kinematics_plus_harmonics_plus_twist(rv):
    t = np.arange(1, 3001) / 1000.0
    angle = 700.0 / 60.0 * ARCSEC_PER_REV * t  # constant speed, no load: no twist
    result, _ = turn(rv, UnitState(), t, angle, 0.0)
    phi = angle / rv.ratio / ARCSEC_PER_RAD
    expected = sum(h.amplitude_arcsec * np.sin(h.order_per_output_rev * phi + h.phase_rad) for h in rv.harmonics)
    np.testing.assert_allclose(result.output_angle_arcsec - angle / rv.ratio, expected, atol=1e-9)
    np.testing.assert_allclose(transmission_error_arcsec(rv, phi), expected, atol=1e-12)


def test_breakaway_is_the_starting_torque_in_each_direction(rv):
    dt = 1e-3
    for sign in (1.0, -1.0):
        torque = sign * np.arange(1, 4001) * 0.5 * dt  # 0.5 N·m/s
        t = np.arange(1, 4001) * dt
        result, _ = turn_with_torque(rv, UnitState(), t, torque, 0.0)
        first = int(np.flatnonzero(result.input_speed_rpm != 0.0)[0])
        truth = starting_torque_truth(rv, sign)
        assert abs(torque[first - 1]) <= truth < abs(torque[first])
        assert np.all(result.input_angle_arcsec[:first] == 0.0)
        assert sign * result.input_angle_arcsec[-1] > 0.0
    assert starting_torque_truth(rv, -1.0) > starting_torque_truth(rv, 1.0)  # the asymmetry of the catalogue entry


def test_running_torque_and_efficiency_truth(catalogue, rv):
    spec = catalogue["RV-110E"]
    sim = spec.sim.transmission
    rated = sim.rated_input_speed_rpm
    assert efficiency_truth(rv, spec.rated_torque_nm, rated, sim.reference_temperature_c) == pytest.approx(
        sim.rated_efficiency_pct / 100.0, rel=1e-12)
    # the viscous part thins with the temperature; the Coulomb part does not
    cold, warm = no_load_torque_truth(rv, 1000.0, 15.0), no_load_torque_truth(rv, 1000.0, 45.0)
    f = rv.friction
    assert cold - warm == pytest.approx(
        (1 - f.asymmetry) * sim.viscous_nm_per_krpm * (math.exp(0.3) - math.exp(-0.6)), rel=1e-9)
    # the input torque at rated load and speed is what the efficiency says
    t_in = float(input_torque_nm(rv, np.array([rated]), np.array([-spec.rated_torque_nm]), 25.0)[0])
    assert spec.rated_torque_nm / (rv.ratio * t_in) == pytest.approx(0.85, rel=1e-12)


def test_sim_transmission_is_typed_and_off_by_default(write, bench_text, catalogue):
    default = load_bench_config()
    assert default.sim.transmission.enabled is False and unit_for_bench(default, catalogue) is None
    text = bench_text.replace("[sim.effects]", "[sim.transmission]\nenabled = true\n"
                              "extra = [{ order = 27.3, amplitude_arcsec = 1.5, phase_deg = 10.0 }]\n\n[sim.effects]")
    unit = unit_for_bench(load_bench_config(write("bench.toml", text)), catalogue)
    assert unit is not None and unit.harmonics[-1].order_per_output_rev == 27.3
    assert unit.harmonics[-1].component is None
    bad = text.replace("phase_deg = 10.0", "phase = 10.0")
    with pytest.raises(ConfigError) as exc:
        load_bench_config(write("bad.toml", bad))
    assert "\n" not in str(exc.value) and "sim.transmission.extra.0.phase" in str(exc.value)

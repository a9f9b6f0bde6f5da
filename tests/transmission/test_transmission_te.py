"""The transmission-error evaluation: on synthetic records (lines one bin apart, an order between bins, a trend,
noise) and on the simulated RV-110E and HFUC-32-100 (through the measuring chain and its compensation), the orders
are found with their components and every result lies within its U of the truth."""

from __future__ import annotations

import math

import numpy as np
import pytest
from tcms_daq.sim.station import StationSensors, record_speed_run, te_profile
from tcms_daq.sim.transmission import te_peak_to_peak_truth, unit_from_spec

from tcms_daq.compensation import Compensator
from tcms_daq.config import packaged_config_dir
from tcms_daq.config.models import StationUncertainty
from tcms_daq.errors import EvaluationError
from tcms_daq.transmission.te import evaluate_transmission_error, te_records
from tcms_daq.uncertainty.station import te_budgets, te_order_name
from tcms_daq.units import ARCSEC_PER_RAD, ARCSEC_PER_REV

# RON 786 (±2″: 1.2″ RMS at low orders), 0.1″ above; a motor encoder with 20″ (input) once per turn; 0.1 ms skew
CHAIN = StationUncertainty(output_encoder_u_arcsec=1.2, output_encoder_high_order_u_arcsec=0.1,
                           input_encoder_u_arcsec=20.0, sync_skew_u_s=1e-4)
SENSORS = StationSensors(sample_rate_hz=1000.0, speed_ripple_pct=0.5, sync_skew_s=1e-4, input_encoder_error_arcsec=20.0)


def _synthetic(lines, ratio=50.0, rpm=600.0, revolutions=1.3, noise=0.05, trend_ppm=200.0, seed=0):
    """Both directions at a constant speed (with a 1 % ripple in time), TE = Σ A·sin(kφ + ϕ) + a trend + noise."""
    rng = np.random.default_rng(seed)
    rate = 1000.0
    duration = revolutions * ratio * 60.0 / rpm
    t = np.arange(int(2 * duration * rate)) / rate
    speed = np.where(t < duration, rpm, -rpm) * (1.0 + 0.01 * np.sin(2 * np.pi * 3.3 * t))
    angle_in = np.cumsum(speed / 60.0 * ARCSEC_PER_REV / rate)
    phi = angle_in / ratio / ARCSEC_PER_RAD
    te = sum(a * np.sin(k * phi + math.radians(p)) for k, a, p in lines)
    angle_out = angle_in / ratio * (1.0 + trend_ppm * 1e-6) + te + noise * rng.standard_normal(t.size)
    return t, angle_in, angle_out


def test_lines_one_bin_apart_between_bins_and_under_a_trend():
    lines = [(1.0, 4.0, 30.0), (2.0, 1.0, 200.0), (39.0, 3.0, 110.0), (40.0, 2.0, 250.0), (36.75, 1.5, 80.0)]
    t, a_in, a_out = _synthetic(lines)
    ev = evaluate_transmission_error(t, a_in, a_out, ratio=50.0)
    found = {round(ln.order_per_output_rev, 2): ln for ln in ev.te_orders}
    assert sorted(found) == [1.0, 2.0, 36.75, 39.0, 40.0]
    for k, a, p in lines:
        line = found[round(k, 2)]
        assert line.amplitude_arcsec == pytest.approx(a, abs=0.02)
        assert (line.phase_deg - p + 180.0) % 360.0 - 180.0 == pytest.approx(0.0, abs=1.0)
    for d in ev.per_direction.values():
        assert d.scale_mismatch_ppm == pytest.approx(200.0, abs=2.0)
        phi = np.linspace(d.phi_start_rad, d.phi_end_rad, 200_001)
        truth = sum(a * np.sin(k * phi + math.radians(p)) for k, a, p in lines)
        assert d.peak_to_peak_arcsec == pytest.approx(float(np.ptp(truth)), abs=0.05)
    assert ev.warnings and "ppm" in ev.warnings[0]


def test_less_than_one_revolution_is_refused():
    t, a_in, a_out = _synthetic([(3.0, 1.0, 0.0)], revolutions=0.8)
    with pytest.raises(EvaluationError, match="covers 0.[0-9]+ output revolutions"):
        evaluate_transmission_error(t, a_in, a_out, ratio=50.0)


def _within_u(unit, ev, budgets):
    truth = {round(h.order_per_output_rev, 3): h.amplitude_arcsec for h in unit.harmonics}
    d = ev.per_direction["forward"]
    pp = te_peak_to_peak_truth(unit, d.phi_start_rad, d.phi_end_rad)
    for name, budget in budgets.items():
        if name.startswith("te_order_"):
            expected = truth[round(float(name.split("_")[2]), 3)]
        else:
            expected = pp
        assert abs(budget.value - expected) <= budget.expanded, (name, budget.value, expected, budget.expanded)


@pytest.mark.parametrize("name", ["RV-110E", "HFUC-32-100"])
def test_simulated_unit_within_u_with_its_components(catalogue, name):
    spec = catalogue[name]
    unit = unit_from_spec(spec)
    teeth = spec.kinematics.teeth(spec.kind)
    chain = Compensator.from_geometry(packaged_config_dir() / "geometry-sim.toml")
    run = record_speed_run(unit, te_profile(2000.0, unit.ratio, 1.15, 0.02 * spec.rated_torque_nm), SENSORS,
                           seed=11, measuring_chain=chain.encoder_reading)
    c = run.columns
    raw = te_records(c["time_s"], c["input_angle_arcsec"], c["output_angle_arcsec"], ratio=unit.ratio)
    slope = np.polyfit(raw["forward"].phi_rad, raw["forward"].te_arcsec, 1)[0] / ARCSEC_PER_RAD
    assert slope == pytest.approx(1.0 / chain.meta["k"] - 1.0, rel=1e-3)  # the chain's scale, uncompensated
    output = chain.apply(c["output_angle_arcsec"], c["output_torque_nm"])  # the compensated output angle
    ev = evaluate_transmission_error(c["time_s"], c["input_angle_arcsec"], output, ratio=unit.ratio, teeth=teeth)
    assert all(abs(d.scale_mismatch_ppm) < 1.0 for d in ev.per_direction.values())
    named = {round(ln.order_per_output_rev, 3): ln.components for ln in ev.te_orders}
    for h in unit.harmonics:  # every order of the unit found, and named by its component
        assert h.component in named[round(h.order_per_output_rev, 3)], (h, named)
    assert set(named) == {round(h.order_per_output_rev, 3) for h in unit.harmonics}
    budgets = te_budgets(c["time_s"], c["input_angle_arcsec"], output, ev, CHAIN, teeth=teeth)
    assert set(budgets) >= {"transmission_error_arcsec", *(te_order_name(ln) for ln in ev.te_orders)}
    _within_u(unit, ev, budgets)
    # the input's order carries the input encoder's error (20″/i): its U says so
    line = min(ev.te_orders, key=lambda ln: abs(ln.order_per_output_rev - unit.ratio))
    assert budgets[te_order_name(line)].dominant == "input encoder (once per input turn)"


def test_encoder_line_is_exact_where_the_peak_to_peak_is_linear():
    """One large order-1 line: the peak-to-peak is 2·|A + e₁| (the order-2 part of the encoder's error cancels at the
    maximum and the minimum, half a revolution apart), so the output encoder's line is 2·u/√2 to first order. With
    a few hundred plain draws (one set for every record) it was 3–5 % off; the whitened draws make it exact."""
    chain = StationUncertainty(output_encoder_u_arcsec=1.2)
    for lines in ([(1.0, 20.0, 30.0)], [(1.0, 12.0, 30.0), (40.0, 0.5, 10.0)]):
        t, a_in, a_out = _synthetic(lines, trend_ppm=0.0, noise=0.02)
        ev = evaluate_transmission_error(t, a_in, a_out, ratio=50.0)
        budget = te_budgets(t, a_in, a_out, ev, chain)["forward_transmission_error_arcsec"]
        line = next(ln for ln in budget.lines if ln.source == "output encoder (orders 1–2)")
        assert line.contribution == pytest.approx(2.0 * 1.2 / math.sqrt(2.0), rel=0.01), lines


def test_skew_line_covers_what_a_skew_does_to_the_peak_to_peak(catalogue):
    """A skew moves the two directions' lines in opposite senses (it carries the speed and its ripple at the input's
    order): the larger direction's peak-to-peak rises for a skew of either sign. A central difference of ±u through
    that maximum (the old line) gave almost nothing; the skew drawn in the lines' Monte Carlo gives about what a
    record latched ±u off shows."""
    spec = catalogue["RV-110E"]
    unit = unit_from_spec(spec)
    u_skew = 3e-4

    def run(skew_s):
        sensors = StationSensors(sample_rate_hz=1000.0, speed_ripple_pct=0.5, sync_skew_s=skew_s)
        c = record_speed_run(unit, te_profile(2000.0, unit.ratio, 1.05, 0.02 * spec.rated_torque_nm), sensors,
                             seed=3).columns
        ev = evaluate_transmission_error(c["time_s"], c["input_angle_arcsec"], c["output_angle_arcsec"],
                                         ratio=unit.ratio)
        return c, ev

    c, ev = run(0.0)
    budgets = te_budgets(c["time_s"], c["input_angle_arcsec"], c["output_angle_arcsec"], ev,
                         StationUncertainty(sync_skew_u_s=u_skew))
    moved = [run(s)[1] for s in (u_skew, -u_skew)]
    for name, value in (("transmission_error_arcsec", lambda e: e.transmission_error_arcsec),
                        ("forward_transmission_error_arcsec", lambda e: e.per_direction["forward"].peak_to_peak_arcsec),
                        ("reverse_transmission_error_arcsec", lambda e: e.per_direction["reverse"].peak_to_peak_arcsec)):
        actual = max(abs(value(m) - value(ev)) for m in moved)
        line = next(ln for ln in budgets[name].lines if ln.source.startswith("synchronisation"))
        assert actual > 0.1
        assert line.contribution >= 0.7 * actual, (name, line.contribution, actual)

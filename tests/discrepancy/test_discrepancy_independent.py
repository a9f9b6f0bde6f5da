"""The workflow on data the project did not generate (``sim/independent.py``: a two-slope spring with a Dahl loop,
effects written from their physics): sizes right on the same rows, on the simulation's own time grid and at 1 kHz,
nothing extra named; and the pieces those depend on, each checked on its own (cheap: no workflow run).

The full trials over seeds and families are ``python -m tcms_daq.sim.independent --seeds 5 --grid both [--rate-hz
1000]`` (docs/discrepancy.md); these few runs are what CI can afford."""

from __future__ import annotations

import math

import numpy as np
import pytest
from tcms_daq.sim import independent as ind

from tcms_daq.discrepancy import effects as fx
from tcms_daq.discrepancy.design import build_design
from tcms_daq.discrepancy.selection import Columns, scan_nonlinear
from tcms_daq.discrepancy.stored import applied_torque_estimate
from tcms_daq.samples import Samples

# one loop per rate: ±800 N·m at 200 and 600 N·m/s, 30 s
SMALL = ind.Programme(loops_per_rate=1)


def _named_right(family: str, seed: int, programme: ind.Programme, grid: str) -> ind.Outcome:
    o = ind.run_family(family, seed, programme, grid)
    assert o.named == list(o.truth), o.to_dict()
    assert all(abs(e) <= 0.10 for e in o.errors.values()), o.to_dict()
    assert o.verdict == ("explained" if o.truth else "consistent"), o.to_dict()
    return o


@pytest.mark.parametrize(("family", "rate_hz", "grid", "loops"), [
    ("torque_reading_offset", 1000.0, "same_rows", 1),  # the first-order form: −45 %
    ("torque_reading_offset", 50.0, "own_grid", 1),  # the first-order form: −42 %
    # refined into the band around the signal period: 78.8″, not named (with one loop per rate, 4 loops in all,
    # it is selected in 3 of the 4 outer folds: unstable)
    ("gear_mesh", 50.0, "same_rows", 2),
], ids=["offset-1kHz", "offset-own-grid", "mesh-95"])
def test_independent_physics_is_named_with_its_size(family, rate_hz, grid, loops):
    o = _named_right(family, 1, ind.Programme(rate_hz=rate_hz, loops_per_rate=loops), grid)
    assert o.pairing == {"same_rows": "same_rows", "own_grid": "time_grid"}[grid]


def test_a_torque_offset_is_within_a_few_percent_over_seeds():
    """Not only within 10 %: no bias of the noise (the first-order form was −6 … −8 % at 50 Hz)."""
    errors = [_named_right("torque_reading_offset", seed, SMALL, "same_rows").errors[fx.TORQUE_ZERO_OFFSET]
              for seed in (2, 3)]
    assert max(abs(e) for e in errors) < 0.05, errors


def test_the_simulated_bench_hides_a_torque_offset_in_the_reading():
    from tcms_daq.sim.effects import EffectsHook, effects_from_table

    t = np.linspace(0.0, 4.0, 200)
    applied = 500.0 * np.sin(t)
    cols = {"time_s": t, "applied_torque_nm": applied, "torque_signal_nm": applied.copy(),
            "angle_signal_arcsec": applied / 5.0, "true_angle_arcsec": applied / 5.0}
    out = EffectsHook(effects_from_table({fx.TORQUE_ZERO_OFFSET: {"offset_nm": 6.0}}))(dict(cols))
    np.testing.assert_allclose(out["torque_signal_nm"], applied + 6.0)
    np.testing.assert_allclose(out["angle_signal_arcsec"], cols["angle_signal_arcsec"])


def test_the_history_free_curve_drops_a_friction_loop_and_the_shift_is_exact():
    p = ind.Programme(rate_hz=200.0, loops_per_rate=1, torque_noise_nm=0.0)
    t = ind._grid(p)
    torque = ind.torque_path(p, t)
    angle = ind.reducer_arcsec(torque)
    data = build_design(Samples(t, torque, angle), Samples(t, torque, angle))
    inner = np.abs(torque) < 600  # away from the tips, where the loop closes
    off = (data.history_free_on_rows - ind.spring_arcsec(torque))[inner]
    assert np.std(off) < 0.1  # 0.07″ (the bins round the spring's kinks); the loop itself is ±1.5″
    error = (fx.torque_shift(data, 6.0) - (ind.spring_arcsec(torque - 6.0) - ind.spring_arcsec(torque)))[inner]
    assert np.sqrt(np.mean(error**2)) < 0.05  # 0.037″ of a 1.8″ signature


def test_a_free_period_beside_the_signal_periods_band_stays_out_of_it():
    """95″ is 1.2 cycles per 347″ of angle from the 72″ signal period, just outside the band the free-period grid
    leaves out; a parabola through the grid's neighbour across the band put it at 78.8″, inside."""
    t = np.arange(0.0, 60.0, 0.02)
    torque = 800.0 * np.sin(2 * math.pi * t / 20.0)
    sim = torque / 4.6  # ±174″: a 347″ span
    rng = np.random.default_rng(5)
    measured = sim + 0.7 * np.sin(2 * math.pi * sim / 95.0 + 0.4) + rng.normal(0.0, 0.2, len(t))
    data = build_design(Samples(t, torque, measured), Samples(t, torque, sim))
    assert np.ptp(sim) / 95.0 - np.ptp(sim) / 72.0 < -1.0  # the case: just over one cycle apart
    period = scan_nonlinear(Columns(data), fx.PERIODIC_ERROR, data.residual_arcsec, np.arange(len(t)))
    assert period == pytest.approx(95.0, rel=0.01)


def test_the_applied_torque_estimate_keeps_the_corners():
    """A moving average over 50 ms rounded every corner of the programme (a ramp into a hold at a tip and out of
    it) by up to 3.8 N·m; the model's loop then turned early (0.03″ of structure after a 1 M-sample hidden skew:
    partially_explained). Ramps at 200 and 600 N·m/s with 50 ms holds at 13.75 kHz, the trials' noise density."""
    rate_hz, hold_s = 13_750.0, 0.05
    knots_t = np.cumsum([0.0, 800 / 200, hold_s, 1600 / 600, hold_s, 800 / 200])
    knots_T = np.array([0.0, 800.0, 800.0, -800.0, -800.0, 0.0])
    t = np.arange(0.0, knots_t[-1], 1.0 / rate_hz)
    applied = np.interp(t, knots_t, knots_T)
    reading = applied + np.random.default_rng(1).normal(0.0, 0.3 * math.sqrt(50.0 / rate_hz), len(t))
    error = applied_torque_estimate(t, reading) - applied
    near = np.any(np.abs(t[:, None] - knots_t[None, 1:-1]) < 0.05, axis=1)
    assert np.sqrt(np.mean(error[near] ** 2)) < 0.5  # 0.27 N·m (1.02 with the moving average)
    assert np.max(np.abs(error)) < 2.0  # 1.4 N·m (3.8)


def test_the_trials_report_rates_per_family():
    o = [ind.Outcome("play", s, True, "explained", ["backlash"], {"backlash": 2.5}, {"backlash": e}, None, 1.0)
         for s, e in ((1, 0.02), (2, 0.15))]
    o.append(ind.Outcome("null", 1, True, "partially_explained", ["time_skew"], {}, {}, None, 1.0, "own_grid"))
    o.append(ind.Outcome("lost_counts", 1, False, "unexplained", ["thermal_drift"], {}, {}, True, 1.0))
    summary, totals = ind.summarise(o), ind.totals(o)
    assert summary["play"]["within_10_percent"] == 0.5 and summary["null@own_grid"]["extra_names"] == 1.0
    assert summary["lost_counts"]["located"] == 1.0 and summary["lost_counts"]["explained"] == 0.0
    assert totals == {"catalogue_runs": 3, "with_extra_names": 1, "hidden_runs": 2, "hidden_named": 2,
                      "named_parameters": 2, "within_10_percent": 1, "out_of_catalogue_runs": 1, "explained": 0,
                      "located": 1}

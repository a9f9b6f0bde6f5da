"""The verdict: is what remains noise? Catalogue effects are ``explained``, no effect is ``consistent``, and
effects outside the catalogue are never ``explained`` — the ``unexplained`` block says where and what shape.

Two sources of data: the project's simulated bench (``sim.trials`` with ``sim.unmodelled``) and, so the
verdict is not only checked on data the project made, a small generator of its own here (a linear spring
with white sensor noise, loops at two rates) written from the physics without the project's code.
"""

from __future__ import annotations

import numpy as np
import pytest
from tcms_daq.sim.trials import make_pair
from tcms_daq.sim.unmodelled import UNMODELLED

from tcms_daq.discrepancy.verdict import noise_floor_arcsec
from tcms_daq.discrepancy.workflow import run_discrepancy
from tcms_daq.samples import Samples

# -- an independent generator: spring, white noise, triangle loops at 200 and 600 N·m/s, 100 Hz -----------

K_ARCSEC_PER_NM = 60.0 / 300.0  # 300 N·m/arcmin


def spring_loops(seed: int, noise_arcsec: float = 0.2, rate_hz: float = 100.0):
    """(time s, torque N·m, true twist ″, noisy reading ″) of ±600 N·m loops, three at each of two rates."""
    rng = np.random.default_rng(seed)
    legs, level = [], 0.0
    for rate in (200.0, 600.0):
        for target in [-600.0] + [600.0, -600.0] * 3:
            n = int(abs(target - level) / rate * rate_hz)
            legs.append(np.linspace(level, target, n, endpoint=False))
            level = target
    torque = np.concatenate(legs)
    t = np.arange(len(torque)) / rate_hz
    twist = K_ARCSEC_PER_NM * torque
    return t, torque, twist, twist + rng.normal(0.0, noise_arcsec, len(t))


def analyse(t, torque, measured, simulated):
    return run_discrepancy(Samples(t, torque, measured), Samples(t, torque, simulated))


def test_noise_floor_from_second_differences_ignores_smooth_structure_and_steps():
    rng = np.random.default_rng(3)
    t = np.arange(20000) / 100.0
    smooth = 3.0 * np.sin(2 * np.pi * t / 40.0) + 2.0 * (t > 100.0)  # slow periodicity and one step
    for sigma in (0.05, 0.2, 1.0):
        assert noise_floor_arcsec(smooth + rng.normal(0, sigma, len(t))) == pytest.approx(sigma, rel=0.05)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_own_generator_noise_only_is_consistent(seed):
    t, torque, twist, reading = spring_loops(seed)
    result = analyse(t, torque, reading, twist)
    assert result.verdict.verdict == "consistent", result.verdict.to_dict()
    assert result.names == [] and result.verdict.unexplained is None
    assert result.verdict.noise_floor_arcsec == pytest.approx(0.2, rel=0.1)


def test_own_generator_a_step_is_not_explained_and_is_located():
    t, torque, twist, reading = spring_loops(4)
    t_step = 0.6 * t[-1]
    result = analyse(t, torque, reading + 1.5 * (t >= t_step), twist)
    v = result.verdict
    assert v.verdict in ("partially_explained", "unexplained"), v.to_dict()
    assert v.provisional and all(e["provisional"] for e in result.to_dict()["effects"])
    assert v.unexplained["shape"] == "step", v.unexplained["shapes_considered"]
    assert v.unexplained["shape_detail"]["at_time_s"] == pytest.approx(t_step, abs=0.02 * t[-1])
    assert v.unexplained["shape_detail"]["height_arcsec"] == pytest.approx(1.5, rel=0.15)
    assert "step" in result.to_dict()["verdict_words"]


def test_own_generator_a_sensitivity_change_is_a_catalogue_effect_and_explained():
    """On a pure spring an encoder scale error and a torsion of the measuring chain look alike (both ∝ T):
    the workflow adds one of the look-alikes and says so, and the remainder is noise."""
    t, torque, twist, reading = spring_loops(5)
    result = analyse(t, torque, reading + 0.01 * twist, twist)  # encoder scale 1 % off
    in_model = [a.names for a in result.aliases if a.in_model]
    assert result.names == ["scale_error"] or any("scale_error" in names for names in in_model), result.to_dict()
    assert result.verdict.verdict == "explained", result.verdict.to_dict()


# -- the simulated bench: catalogue cases (incl. a 6 N·m torque offset) and out-of-catalogue ones ---------


@pytest.mark.parametrize("table", [
    {"torque_zero_offset": {"offset_nm": 6.0}},
    {"torque_zero_offset": {"offset_nm": 6.0}, "thermal_drift": {"rate_arcsec_per_s": 0.03}},
], ids=["torque_offset_6nm", "torque_offset_6nm+drift"])
def test_a_6_nm_torque_offset_alone_and_paired_is_explained(table):
    measured, simulated, _ = make_pair(table, 21)
    result = run_discrepancy(measured, simulated)
    assert sorted(result.names) == sorted(table)
    assert result.verdict.verdict == "explained", result.verdict.to_dict()
    offset = {e.name: e.parameters for e in result.effects}["torque_zero_offset"]["offset_nm"]
    assert offset == pytest.approx(6.0, rel=0.10)


@pytest.fixture(scope="module")
def unmodelled_result():
    cache: dict = {}

    def get(case: str, seed: int = 11):
        if (case, seed) not in cache:
            measured, simulated, floor = make_pair({}, seed, unmodelled=UNMODELLED[case])
            cache[case, seed] = (run_discrepancy(measured, simulated), measured, floor)
        return cache[case, seed]

    return get


@pytest.mark.parametrize("case", sorted(UNMODELLED))
@pytest.mark.parametrize("seed", [11, 12])
def test_out_of_catalogue_is_never_explained(unmodelled_result, case, seed):
    result, _, floor = unmodelled_result(case, seed)
    v = result.verdict
    assert v.verdict in ("partially_explained", "unexplained"), (case, result.names, v.to_dict())
    assert v.noise_floor_arcsec == pytest.approx(floor, rel=0.15)
    block = v.unexplained
    assert block is not None and block["structured_rms_arcsec"] > 0.5 * floor and block["spans"]
    assert result.to_dict()["names_provisional"] is True


def _shape(result):
    return result.verdict.unexplained["shape"], result.verdict.unexplained["shape_detail"]


def test_encoder_slip_is_located_as_a_step_mid_test(unmodelled_result):
    result, measured, _ = unmodelled_result("encoder_slip")
    shape, detail = _shape(result)
    t = measured.time_s
    assert shape == "step"
    assert detail["at_time_s"] == pytest.approx(t[0] + 0.5 * np.ptp(t), abs=0.02 * np.ptp(t))
    assert detail["height_arcsec"] == pytest.approx(2.0, rel=0.15)


def test_clipping_is_located_as_a_saturation_at_the_upper_end(unmodelled_result):
    result, measured, _ = unmodelled_result("range_clipping")
    shape, detail = _shape(result)
    assert shape == "saturation" and detail["end"] == "upper"
    # the knee is in simulated-angle coordinates: above it lie about as many samples as the reading clipped
    clipped_share = np.mean(measured.angle_arcsec >= measured.angle_arcsec.max() - 1e-9)
    above_knee = np.mean(result.data.sim_angle_arcsec >= detail["from_angle_arcsec"])
    assert above_knee == pytest.approx(clipped_share, abs=0.05)
    assert detail["slope_arcsec_per_arcsec"] == pytest.approx(-1.0, abs=0.2)


def test_glitches_are_counted_as_spikes(unmodelled_result):
    result, measured, _ = unmodelled_result("encoder_glitches")
    shape, detail = _shape(result)
    injected = max(1, int(0.005 * len(measured.time_s)))
    assert shape == "spikes" and detail["count"] == pytest.approx(injected, abs=2)


def test_creep_is_located_as_a_lagged_response(unmodelled_result):
    result, _, _ = unmodelled_result("creep")
    shape, detail = _shape(result)
    assert shape == "lagged_response"
    assert detail["time_constant_s"] == pytest.approx(4.0, rel=0.5)


def test_a_wider_friction_loop_is_located_at_the_reversals(unmodelled_result):
    result, _, _ = unmodelled_result("wider_friction_loop")
    shape, _ = _shape(result)
    assert shape.startswith("transition_after_reversal"), result.verdict.unexplained["shapes_considered"]


def test_a_v_in_torque_fitted_by_look_alikes_is_not_called_explained(unmodelled_result):
    """c·|T| is fitted within the noise by bending + under two cycles of a free-period sine: the sine is
    reported as not identified and the verdict is judged on what the identified names leave."""
    result, _, _ = unmodelled_result("housing_bulge")
    v = result.verdict
    assert v.verdict == "partially_explained"
    assert "periodic_error" in result.names and "periodic_error" in v.not_identified
    assert "cannot be told from a smooth shape" in v.words()
    assert result.to_dict()["names_not_identified"] == v.not_identified


def test_a_million_samples_at_the_same_noise_density_name_the_hidden_pair():
    """13.75 kHz for 73 s (1.0 M samples), sensor noise scaled to the same density as the 50 Hz trials: the
    pair is averaged in blocks (reported) and the hidden time skew + interpolation error are named, not a
    look-alike (issue: it was scale_error)."""
    import dataclasses

    from tcms_daq.sim.trials import CASES, TrialDesign

    base = TrialDesign()
    rate_hz = 13_750.0
    scale = (rate_hz / base.sample_rate_hz) ** 0.5
    design = dataclasses.replace(base, sample_rate_hz=rate_hz, torque_noise_nm=base.torque_noise_nm * scale,
                                 encoder_noise_arcsec=base.encoder_noise_arcsec * scale)
    table = CASES["time_skew+interpolation_error"]
    measured, simulated, _ = make_pair(table, 11, design)
    assert len(measured) >= 1_000_000
    result = run_discrepancy(measured, simulated)
    assert sorted(result.names) == ["interpolation_error", "time_skew"], result.to_dict()
    assert result.pairing.block_samples > 1 and result.to_dict()["pairing"]["rows_analysed"] <= 24_000
    found = {e.name: e.parameters for e in result.effects}
    assert found["time_skew"]["skew_s"] == pytest.approx(0.02, rel=0.10)
    assert found["interpolation_error"]["amplitude_arcsec"] == pytest.approx(0.6, rel=0.10)
    assert result.verdict.verdict == "explained", result.verdict.to_dict()


@pytest.mark.parametrize("case", ["thermal_drift", "scale_error", "backlash", "torque_zero_offset",
                                  "interpolation_error", "thermal_drift+backlash"])
def test_parameter_uncertainties_cover_the_hidden_values(case):
    """The standard uncertainty (k = 1, jackknife over loops) is reported per parameter, in the JSON and in
    model.toml with the fit range and the drift's reference time; over seeds the truth lies within 3 u.
    (time_skew is left out for CI time: −0.74 … +0.05 % at seeds 11–15, at most 2.6 u, in docs/discrepancy.md.)"""
    from tcms_daq.sim.trials import CASES, PRIMARY

    from tcms_daq.discrepancy.model_file import model_from_result, parse_model

    table = CASES[case]
    for seed in (11, 12, 13):
        measured, simulated, _ = make_pair(table, seed)
        result = run_discrepancy(measured, simulated)
        for e in result.effects:
            key = PRIMARY[e.name]
            u = e.standard_uncertainty[key]
            assert 0 < u < 0.05 * abs(table[e.name][key])
            assert abs(e.parameters[key] - table[e.name][key]) <= 3 * u, (seed, e.name, e.parameters, u)
    model = parse_model(model_from_result(result).to_toml())
    assert model.drift_reference_time_s == pytest.approx(measured.time_s[0])
    assert model.fit_range["time_s"] == pytest.approx([measured.time_s[0], measured.time_s[-1]])
    assert {t.name: t.standard_uncertainty for t in model.terms} == result.uncertainties
    assert result.to_dict()["effects"][0]["standard_uncertainty"]


def test_the_trials_run_as_the_workflow_module_names_them():
    import json
    import subprocess
    import sys

    out = subprocess.run([sys.executable, "-m", "tcms_daq.discrepancy.trials", "--seeds", "1", "--case", "null",
                          "--case", "housing_bulge", "--json"], capture_output=True, text=True, timeout=300,
                         check=True).stdout
    summary = json.loads(out)["summary"]
    assert summary["false_naming_rate_null"] == 0.0
    assert summary["out_of_catalogue"]["runs"] == 1 and summary["out_of_catalogue"]["honesty_rate"] == 1.0

"""The compensator: convention θ_c = θ − Σ term, fast path vs exact path, TOML round trip, forward chain."""

import math
import pathlib
from dataclasses import dataclass

import numpy as np
import pytest

from tcms_daq.compensation import (
    TERM_TYPES,
    Compensator,
    Eccentricity,
    Offset,
    Periodic,
    Scale,
    Term,
    Torsion,
    encoder_reading,
    load_compensator,
    measuring_chain_error,
    register_term,
)
from tcms_daq.compensation.terms import Drift, parse_term_spec
from tcms_daq.errors import ConfigError


def full_compensator() -> Compensator:
    return Compensator(
        [
            Scale(0.03),
            Torsion(0.004),
            Offset(1.5),
            Eccentricity(eccentricity_mm=0.01, radius_mm=30.0, phase_rad=0.4),
            Periodic(72.0, 0.4, -0.2),
            Periodic(36.0, 0.1, 0.15),
        ]
    )


@pytest.fixture
def trace():
    rng = np.random.default_rng(3)
    torque = 1000 * np.sin(np.linspace(0, 12, 50_000))
    angle = torque * 0.2 + rng.normal(0, 0.5, torque.size)
    return angle, torque


def test_sign_convention_of_linear_terms():
    # θ_c = θ − offset − s·θ − c·T: an encoder that over-reads by 3 % and 0.004″/N·m is corrected down
    comp = Compensator([Offset(2.0), Scale(0.03), Torsion(0.004)])
    out = comp.apply(np.array([100.0, -100.0]), np.array([1000.0, -1000.0]))
    np.testing.assert_allclose(out, [100 - 2 - 3 - 4, -100 - 2 + 3 + 4])


def test_identity_is_a_copy():
    x = np.array([1.0, 2.0, 3.0])
    out = Compensator.identity().apply(x, 0.0)
    np.testing.assert_array_equal(out, x)
    assert out is not x


def test_fast_path_matches_exact_evaluation(trace):
    # the tabulated periodic terms stay within tolerance/2 of the direct evaluation
    angle, torque = trace
    comp = full_compensator()
    fast = comp.apply(angle, torque)
    exact = comp.apply(angle, torque, exact=True)
    assert np.max(np.abs(fast - exact)) <= comp.tolerance_arcsec / 2 + 1e-9
    # and the exact path is the sum of the terms evaluated one by one
    by_hand = angle - sum(t.evaluate(angle, torque, None) for t in comp.terms)
    np.testing.assert_allclose(exact, by_hand, atol=1e-9)


def test_apply_in_place_and_2d(trace):
    angle, torque = trace
    comp = full_compensator()
    ref = comp.apply(angle, torque)
    buf = angle.copy()
    comp.apply(buf, torque, out=buf)
    np.testing.assert_allclose(buf, ref, atol=1e-12)
    two_d = comp.apply(angle[:1000].reshape(10, 100), torque[:1000].reshape(10, 100))
    np.testing.assert_allclose(two_d.ravel(), ref[:1000], atol=1e-12)
    # a scalar torque broadcasts
    np.testing.assert_allclose(comp.apply(angle[:10], 0.0), comp.apply(angle[:10], np.zeros(10)))


def test_any_span_stays_within_tolerance():
    # the periodic terms are tabulated over their own periods: the span of the data does not matter
    comp = full_compensator()
    for hi in (10.0, 1000.0, 1e5, 1e7, 1e9):
        x = np.linspace(-hi, hi, 5000)
        assert np.max(np.abs(comp.apply(x, 0.0) - comp.apply(x, 0.0, exact=True))) <= comp.tolerance_arcsec / 2
    assert np.isnan(comp.apply(np.array([np.nan, 1.0]), 0.0)[0])


def test_forward_chain_is_inverted_by_apply(trace):
    # the simulator reads the encoder through encoder_reading; apply must give the truth back
    true, torque = trace
    comp = full_compensator()
    reading = comp.encoder_reading(true, torque)
    assert np.max(np.abs(comp.apply(reading, torque, exact=True) - true)) < 1e-8
    err = comp.measuring_chain_error(true, torque)
    np.testing.assert_allclose(err, reading - true)
    # a 3 % scale over-reading dominates: reading ≈ true / (1 − 0.03)
    assert reading[np.argmax(true)] > true.max() * 1.02


def test_geometry_compensator_inverts_the_paper_chain(paper_geometry_path):
    # true = k·reading − c·T (dh_model.md §3.2) with k = 1.1925, c = 0.00395 ″/N·m
    comp = Compensator.from_geometry(paper_geometry_path)
    assert {t.type_name for t in comp.terms} == {"scale", "torsion"}
    reading = np.array([100.0, 400.0])
    torque = np.array([500.0, 1700.0])
    np.testing.assert_allclose(comp.apply(reading, torque), 1.19254417 * reading - 0.0039497684 * torque, rtol=1e-7)
    true = np.array([0.0, 250.0])
    np.testing.assert_allclose(comp.apply(encoder_reading(paper_geometry_path, true, 800.0), 800.0), true, atol=1e-9)
    assert measuring_chain_error(comp, 0.0, 1000.0) == pytest.approx(0.0039497684 * 1000 / 1.19254417, rel=1e-6)


def test_toml_round_trip(tmp_path):
    comp = full_compensator().with_terms(Drift(0.01))
    path = tmp_path / "comp.toml"
    comp.save(path)
    again = load_compensator(path)
    assert again == comp
    x = np.linspace(-300, 300, 101)
    t = np.linspace(0, 10, 101)
    np.testing.assert_allclose(again.apply(x, x * 3, t), comp.apply(x, x * 3, t))


def test_load_geometry_file_as_compensator(paper_geometry_path):
    assert load_compensator(paper_geometry_path) == Compensator.from_geometry(paper_geometry_path)


@pytest.mark.parametrize(
    "text, message",
    [
        ('[[terms]]\ntype = "bogus"\n', "unknown term type 'bogus'"),
        ('[[terms]]\ntype = "scale"\ncoef = 1\n', "unknown key 'coef'"),
        ('[[terms]]\ntype = "periodic"\nperiod_arcsec = -1\n', "period_arcsec > 0"),
        ("x = 1\n", "neither a compensator"),
        ("[[terms]\n", "invalid TOML"),
    ],
)
def test_bad_compensator_files(tmp_path, text, message):
    path = tmp_path / "c.toml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(ConfigError, match=message):
        load_compensator(path)


def test_registry_accepts_new_terms(tmp_path):
    # the discrepancy workflow adds its own term types; they serialise and apply like the built-in ones
    @register_term("test_quadratic_torque")
    @dataclass(frozen=True)
    class QuadraticTorque(Term):
        arcsec_per_nm2: float = 0.0
        linear_params = ("arcsec_per_nm2",)

        def evaluate(self, angle_arcsec, torque_nm, time_s):
            return self.arcsec_per_nm2 * np.asarray(torque_nm, dtype=float) ** 2

        def design_columns(self, angle_arcsec, torque_nm, time_s):
            return (np.asarray(torque_nm, dtype=float) ** 2).reshape(-1, 1)

    try:
        comp = Compensator([Scale(0.01), QuadraticTorque(1e-6)])
        path = tmp_path / "c.toml"
        comp.save(path)
        again = load_compensator(path)
        np.testing.assert_allclose(again.apply(np.array([100.0]), np.array([1000.0])), [100 - 1 - 1])
        assert isinstance(parse_term_spec("test_quadratic_torque"), QuadraticTorque)
        with pytest.raises(ValueError, match="already registered"):
            register_term("scale")(QuadraticTorque)
    finally:
        TERM_TYPES.pop("test_quadratic_torque", None)


def test_periodic_term_value():
    t = Periodic(72.0, sin_arcsec=0.5, cos_arcsec=0.2)
    x = np.array([0.0, 18.0, 36.0])
    np.testing.assert_allclose(
        t.evaluate(x, 0, None), 0.5 * np.sin(2 * np.pi * x / 72) + 0.2 * np.cos(2 * np.pi * x / 72), atol=1e-12
    )
    assert t.max_slope() == pytest.approx(math.hypot(0.5, 0.2) * 2 * math.pi / 72)


def test_drift_needs_time():
    comp = Compensator([Drift(0.5)])
    np.testing.assert_allclose(comp.apply(np.zeros(2), 0.0, np.array([0.0, 2.0])), [0.0, -1.0])
    with pytest.raises(ConfigError, match="time_s"):
        comp.apply(np.zeros(2), 0.0)


def test_untilted_geometry_gives_the_eq2_eccentricity_term(paper_geometry_path):
    # φ = 0 (only a diameter error of the output shaft): k = 1, no torsion shift, Eq. 2 eccentricity instead
    from dataclasses import replace

    from tcms_daq.compensation.geometry import PartErrors, load_geometry

    parts = [PartErrors() for _ in range(6)]
    parts[3] = PartErrors(dd_mm=0.02)
    geom = replace(load_geometry(paper_geometry_path), parts=tuple(parts), eccentricity_phase_rad=0.5)
    comp = Compensator.from_geometry(geom)
    ecc = [t for t in comp.terms if isinstance(t, Eccentricity)]
    assert len(ecc) == 1
    assert ecc[0].eccentricity_mm == pytest.approx(0.02 * 2**0.5)
    assert ecc[0].radius_mm == 30.0 and ecc[0].phase_rad == 0.5
    scale = [t for t in comp.terms if isinstance(t, Scale)][0]
    assert scale.coefficient == 0.0


def test_empty_batch():
    out = full_compensator().apply(np.empty(0), np.empty(0))
    assert out.shape == (0,)


def test_loads_parses_text_like_load(tmp_path):
    from tcms_daq.compensation import Compensator
    from tcms_daq.errors import ConfigError

    comp = Compensator.from_geometry(pathlib.Path(__file__).resolve().parents[2] / "config" / "geometry-sim.toml")
    path = tmp_path / "c.toml"
    comp.save(path)
    assert Compensator.loads(path.read_text(), source="body") == Compensator.load(path)
    with pytest.raises(ConfigError, match=r"^body: invalid TOML"):
        Compensator.loads("[[terms]\n", source="body")
    with pytest.raises(ConfigError, match=r"^body: neither a compensator"):
        Compensator.loads("x = 1\n", source="body")

"""The geometric error model against hand-derived numbers for the paper's Table 2/3 inputs."""

import json
import math
from dataclasses import replace

import numpy as np
import pytest

from tcms_daq.cli import main
from tcms_daq.compensation.geometry import (
    PartErrors,
    assembly_errors,
    eccentricity_error_rad,
    evaluate_geometry,
    geometry_from_dict,
    load_geometry,
)
from tcms_daq.errors import ConfigError


@pytest.fixture
def model_json(paper_geometry_path, capsys):
    assert main(["model", str(paper_geometry_path), "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def test_tilt_angle_from_cli(model_json):
    # Eq. 14 with a = first column of T64 (unnormalised, |a| = 1.000874 because Eq. 4 is first order):
    # the net relative tilt 0.057 − 0.021 = 0.036 rad about y and z gives φ ≈ √2·0.036 = 0.0509 rad;
    # the exact printed chain gives 0.0508935 rad (dh_model.md §1.2).
    assert model_json["phi_rad"] == pytest.approx(0.0508935, abs=1e-6)


def test_t64_translation_from_cli(model_json):
    # T64 = (T15 ΔT15 T56 ΔT56)⁻¹ · T12 ΔT12 T23 ΔT23 T34 ΔT34 (Eq. 9): the S4 origin sits near
    # L23 + L34 − L15 = −48 mm, shifted by the assembly errors to −47.8552 mm (dh_model.md §1.2).
    t64 = np.array(model_json["t64"])
    assert t64.shape == (4, 4)
    assert t64[0][3] == pytest.approx(-47.8552, abs=1e-3)
    assert t64[1][3] == pytest.approx(3.4326, abs=1e-3)
    assert t64[2][3] == pytest.approx(-3.3066, abs=1e-3)
    np.testing.assert_allclose(t64[3], [0, 0, 0, 1])


def test_consistent_scale_and_axial_shift_from_cli(model_json):
    # Consistent completion, σ = +1, plane x_A = L23 + L34 + L47 − L15 = −10 mm: the axis meets the plane
    # 6.694 mm off the encoder axis along the tilt direction, so the nut contact radius is
    # R1' = |e + (R2/cos φ) ê| = 41.739 mm → k = R1'/R2 = 1.1925, and the contact point moves along the
    # shaft by ΔL = s_P + R2 tan φ − L47 = 37.904 + 1.783 − 38 = 1.687 mm (dh_model.md §3.3).
    assert model_json["k"] == pytest.approx(1.1925, abs=2e-3)
    assert model_json["delta_l_mm"] == pytest.approx(1.687, abs=2e-3)
    # 32·ΔL/(G π d⁴) with G = 79.3 GPa, d = 58 mm: 2.3412e-3 ″/(N·m·mm) × 1.687 mm = 0.00395 ″/N·m
    assert model_json["torsion_arcsec_per_nm"] == pytest.approx(0.0039499, rel=1e-3)
    assert model_json["sigma"] == 1
    # equal Δβ = Δγ on every joint (Table 1) tilt the axis along (1, −1)/√2 in the measurement plane
    np.testing.assert_allclose(model_json["tilt_direction"], [2**-0.5, -(2**-0.5)], atol=1e-9)
    assert model_json["measurement_plane_x_mm"] == -10.0
    assert model_json["s_p_mm"] == pytest.approx(37.904, abs=1e-3)


def test_assembly_errors_per_joint(model_json):
    # Eqs. 5 and 8 as printed: δr12 = δr56 = 0; δe23 = |Δd2 − Δd3| + Δc2 = 0.031 + 0.022
    expected = {
        "1-2": (0.0, 0.110, 0.017),
        "2-3": (-0.001, 0.053, 0.017),
        "3-4": (0.028, 0.070, 0.023),
        "1-5": (-0.025, 0.126, 0.013),
        "5-6": (0.0, 0.044, 0.008),
    }
    got = model_json["assembly_errors"]
    assert set(got) == set(expected)
    for joint, (dr, de, dt) in expected.items():
        assert got[joint]["dr_mm"] == pytest.approx(dr, abs=1e-12)
        assert got[joint]["de_mm"] == pytest.approx(de, abs=1e-12)
        assert got[joint]["dt_rad"] == pytest.approx(dt, abs=1e-12)


def test_literal_printed_equations_recorded(model_json):
    # Eq. 15/16 taken literally (square roots of lengths): a = 27.1325, k = 0.6057, PaPt = sqrt(11.658)
    lit = model_json["literal_eq15_16"]
    assert lit["a"] == pytest.approx(27.1325, abs=1e-3)
    assert lit["k"] == pytest.approx(0.6057, abs=1e-3)
    assert lit["pa_pt"] == pytest.approx(3.414, abs=1e-3)
    assert lit["eq16_bracket"] == pytest.approx(-30.953, abs=1e-2)
    assert "inconsistent" in lit["note"]


def test_other_sign_and_exact_rotations(paper_geometry_path):
    geom = load_geometry(paper_geometry_path)
    minus = evaluate_geometry(replace(geom, sigma=-1))
    assert minus.k == pytest.approx(0.8101, abs=1e-3)  # dh_model.md §3.3, σ = −1 branch
    assert minus.delta_l_mm == pytest.approx(-1.879, abs=2e-3)
    exact = evaluate_geometry(replace(geom, rotations="exact"))
    assert exact.phi_rad == pytest.approx(0.0509094, abs=1e-6)  # exact rotations, §6 table
    assert exact.k == pytest.approx(1.19267, abs=2e-4)
    assert exact.delta_l_mm == pytest.approx(1.7390, abs=2e-3)


def test_perfect_parts_give_no_error(paper_geometry_path):
    # the plane through the nominal point: every correction vanishes for zero manufacturing errors
    geom = replace(load_geometry(paper_geometry_path), parts=tuple(PartErrors() for _ in range(6)))
    m = evaluate_geometry(geom)
    assert m.phi_rad == 0.0
    assert m.k == 1.0
    assert m.delta_l_mm == pytest.approx(0.0, abs=1e-12)
    np.testing.assert_allclose(m.t64[0, 3], -48.0)


def test_errors_scale_linearly_to_zero(paper_geometry_path):
    # scaling every Table-3 input by ε makes k − 1 and ΔL proportional to ε for small ε (dh_model.md §3.2)
    geom = load_geometry(paper_geometry_path)

    def scaled(eps):
        parts = tuple(PartErrors(p.dl_mm * eps, p.dd_mm * eps, p.dtau_rad * eps, p.dc_mm * eps) for p in geom.parts)
        return evaluate_geometry(replace(geom, parts=parts))

    a, b = scaled(1e-3), scaled(2e-3)
    assert (b.k - 1) / (a.k - 1) == pytest.approx(2.0, rel=1e-2)
    assert b.delta_l_mm / a.delta_l_mm == pytest.approx(2.0, rel=1e-2)


def test_phi_zero_uses_eccentricity_of_eq2(paper_geometry_path):
    # only the output shaft's diameter error: δe34 = 0.02 mm on y and z (Table 1), no tilt → k = 1, Eq. 2
    parts = [PartErrors() for _ in range(6)]
    parts[3] = PartErrors(dd_mm=0.02)
    m = evaluate_geometry(replace(load_geometry(paper_geometry_path), parts=tuple(parts)))
    assert m.phi_rad == 0.0 and m.k == 1.0
    np.testing.assert_allclose(m.eccentricity_mm, [0.02, 0.02], atol=1e-12)
    assert m.notes and "Eq. 2" in m.notes[0]
    # Eq. 2 at θ = 90°: atan(e/R1)
    assert eccentricity_error_rad(math.pi / 2, 0.03, 30.0) == pytest.approx(math.atan(0.03 / 30.0))
    assert eccentricity_error_rad(0.0, 0.03, 30.0) == 0.0


@pytest.mark.parametrize(
    "mutate, message",
    [
        (lambda d: d.pop("structure"), "missing table [structure]"),
        (lambda d: d["structure"].pop("r2_mm"), "missing key 'r2_mm'"),
        (lambda d: d["structure"].update(r2_mm="35"), "finite number"),
        (lambda d: d["parts"]["1"].update(dtua_rad=0.1), "unknown key 'dtua_rad'"),
        (lambda d: d.update(model={"sigma": 2}), "sigma"),
    ],
)
def test_bad_geometry_is_a_config_error(mutate, message):
    data = {
        "structure": {"l23_mm": 5, "l34_mm": 67, "l15_mm": 120, "l47_mm": 38, "r2_mm": 35, "shaft_diameter_mm": 58},
        "parts": {"1": {"dd_mm": 0.1}},
    }
    mutate(data)
    with pytest.raises(ConfigError, match=message.replace("[", r"\[").replace("]", r"\]")):
        geometry_from_dict(data, "g.toml")


def test_model_cli_bad_file(tmp_path, capsys):
    bad = tmp_path / "g.toml"
    bad.write_text("structure = [", encoding="utf-8")
    assert main(["model", str(bad)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("tcms: error:") and "invalid TOML" in err and "\n" not in err
    assert main(["model", str(tmp_path / "missing.toml")]) == 2


def test_model_cli_human_output(paper_geometry_path, capsys):
    assert main(["model", str(paper_geometry_path)]) == 0
    out = capsys.readouterr().out
    assert "0.0508935" in out and "1.19254" in out


def test_assembly_errors_match_eq1_except_printed_zeros(paper_geometry_path):
    # Eq. 5/8 differ from the generic Eq. 1 only in δr12 = δr56 = 0 (dh_model.md §1.1)
    geom = load_geometry(paper_geometry_path)
    a = assembly_errors(geom)
    assert a["1-2"].dr_mm == 0.0 and a["5-6"].dr_mm == 0.0
    assert a["3-4"].dr_mm == pytest.approx(geom.part(3).dl_mm + geom.part(4).dl_mm)

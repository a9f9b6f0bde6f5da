"""Reducer kinematics: tooth numbers → ratio and the order of each component per output revolution, against hand-
computed cases and against the gear train's angular-velocity equations solved numerically (an independent route to
the same orders); the catalogue's tooth numbers give its ratios, and a wrong one is a one-line ConfigError."""

from __future__ import annotations

import numpy as np
import pytest

from tcms_daq.config import load_reducer_catalogue
from tcms_daq.errors import ConfigError
from tcms_daq.transmission.kinematics import (
    COMPONENTS,
    Teeth,
    component_orders_per_output_rev,
    components_at,
    order_table,
    ratio,
)


def test_rv_orders_by_hand():
    # Z1 = 10, Z2 = 40, Zp = 40: i = 1 + 40·40/10 = 161; pins − 1 = 39; crank relative to the carrier 160·10/40 = 40
    teeth = Teeth("rv", input_gear=10, spur_gear=40, crankshafts=3, cycloid=39, pins=40)
    assert ratio(teeth) == 161.0
    assert component_orders_per_output_rev(teeth) == {
        "output": 1.0, "pin_ring": 39.0, "crankshaft": 40.0, "cycloid_disc": 40.0, "input_pinion": 160.0,
        "input": 161.0, "spur_mesh": 1600.0, "cycloid_mesh": 1560.0}


def test_rv_non_integer_ratio_by_hand():
    # RV-110E 175.28 = 1 + 40·61/14 (printed to two decimals); the crankshaft still turns 40 times per output turn
    teeth = Teeth("rv", input_gear=14, spur_gear=61, crankshafts=2, cycloid=39, pins=40)
    assert ratio(teeth) == pytest.approx(175.2857142857, rel=1e-12)
    orders = component_orders_per_output_rev(teeth)
    assert orders["crankshaft"] == pytest.approx(40.0, rel=1e-12)
    assert orders["input"] == pytest.approx(1227 / 7, rel=1e-12)
    assert orders["spur_mesh"] == pytest.approx(61 * 40, rel=1e-12)  # Z1·(i − 1) = Z2·Zp


def test_harmonic_orders_by_hand():
    # Zf = 200, Zcs = 202: i = 200/2 = 100; the wave against the circular spline 2i = 200, against the flexspline
    # 2(i + 1) = 202
    teeth = Teeth("harmonic", flexspline=200, circular_spline=202)
    assert ratio(teeth) == 100.0
    assert component_orders_per_output_rev(teeth) == {
        "output": 1.0, "wave_generator": 100.0, "circular_spline": 200.0, "flexspline": 202.0, "tooth_mesh": 20200.0}
    labels = {row.label: row.order_per_output_rev for row in order_table(teeth)}
    # the wave generator's 2× is the circular spline's own order: named by that component only
    assert "wave_generator 2×" not in labels and labels["circular_spline"] == 200.0
    assert labels["output 2×"] == 2.0 and labels["flexspline 2×"] == 404.0
    assert ratio(Teeth("harmonic", flexspline=160, circular_spline=162)) == 80.0


def _solve_rv_speeds(z1: int, z2: int, zp: int) -> dict[str, float]:
    """Angular velocities (per unit output speed, case frame) from the mesh equations of an RV train, solved as a
    linear system: unknowns ω_in, ω_crank (absolute), ω_disc; the disc turns with the carrier (ω_disc = 1), the
    cycloid (Zc = Zp − 1 lobes) rolls on the fixed pins with its centre carried round by the crank eccentric
    (Zp·(0 − ω_crank) = Zc·(ω_disc − ω_crank)), and the input pinion meshes externally with the crank's spur gear
    inside the carrier (Z1·(ω_in − 1) = −Z2·(ω_crank − 1))."""
    zc = zp - 1
    a = np.array([[0.0, 0.0, 1.0],
                  [0.0, -zp + zc, -zc],
                  [z1, z2, 0.0]])
    b = np.array([1.0, 0.0, z1 + z2])
    w_in, w_crank, w_disc = np.linalg.solve(a, b)
    return {"input": w_in, "crank_abs": w_crank, "crank_rel_carrier": w_crank - 1.0, "disc": w_disc}


@pytest.mark.parametrize(("z1", "z2", "zp"), [(10, 40, 40), (14, 61, 40), (32, 26, 44), (12, 36, 40)])
def test_rv_orders_agree_with_the_gear_trains_equations(z1, z2, zp):
    speeds = _solve_rv_speeds(z1, z2, zp)
    teeth = Teeth("rv", input_gear=z1, spur_gear=z2, crankshafts=3, cycloid=zp - 1, pins=zp)
    orders = component_orders_per_output_rev(teeth)
    assert orders["input"] == pytest.approx(abs(speeds["input"]), rel=1e-12)
    assert orders["crankshaft"] == pytest.approx(abs(speeds["crank_rel_carrier"]), rel=1e-12)
    assert orders["pin_ring"] == pytest.approx(abs(speeds["crank_abs"]), rel=1e-12)  # the eccentric in the case
    assert orders["cycloid_disc"] == pytest.approx(abs(speeds["disc"] - speeds["crank_abs"]), rel=1e-12)
    assert orders["input_pinion"] == pytest.approx(abs(speeds["input"] - 1.0), rel=1e-12)


def test_harmonic_orders_agree_with_the_mesh_equation():
    # the flexspline (Zf) meshes with the fixed circular spline (Zcs) at the two ends of the wave; in the wave's
    # frame both splines' teeth pass the mesh at the same rate: Zf·(ω_fs − ω_wg) = Zcs·(0 − ω_wg)
    zf, zcs = 200, 202
    w_wg = 1.0 / ((zf - zcs) / zf)  # per unit flexspline speed: ω_fs = ω_wg·(Zf − Zcs)/Zf
    orders = component_orders_per_output_rev(Teeth("harmonic", flexspline=zf, circular_spline=zcs))
    assert orders["wave_generator"] == pytest.approx(abs(w_wg), rel=1e-12)
    assert orders["flexspline"] == pytest.approx(2 * abs(w_wg - 1.0), rel=1e-12)


def test_components_at_names_only_orders_of_the_kinematics():
    table = order_table(Teeth("rv", input_gear=10, spur_gear=40, crankshafts=3, cycloid=39, pins=40))
    assert [r.label for r in components_at(39.2, 0.5, table)] == ["pin_ring"]
    assert sorted(r.label for r in components_at(40.0, 0.5, table)) == ["crankshaft", "cycloid_disc"]
    assert components_at(27.0, 0.5, table) == []
    assert [r.label for r in components_at(78.0, 0.25, table)] == ["pin_ring 2×"]
    assert sorted(r.label for r in components_at(39.6, 0.5, table)) == ["crankshaft", "cycloid_disc"]


def test_teeth_must_fit_the_kind():
    with pytest.raises(ValueError, match="one more than its cycloid"):
        Teeth("rv", input_gear=10, spur_gear=40, crankshafts=3, cycloid=40, pins=40)
    with pytest.raises(ValueError, match="need"):
        Teeth("rv", input_gear=10, spur_gear=40)
    with pytest.raises(ValueError, match="not a tooth number"):
        Teeth("harmonic", flexspline=200, circular_spline=202, pins=40)


def test_catalogue_kinematics_give_its_ratios(catalogue):
    for spec in catalogue.values():
        assert spec.kinematics is not None, spec.name
        teeth = spec.kinematics.teeth(spec.kind)
        assert ratio(teeth) == pytest.approx(spec.ratio, abs=0.005), spec.name
        for key in spec.kinematics.assumed:  # what no vendor text gives is marked assumed, with its reason
            assert key in type(spec.kinematics).model_fields
        assert spec.kinematics.sources, spec.name
        for h in spec.sim.transmission.harmonics:
            assert h.component in COMPONENTS[spec.kind]
    assert catalogue["RV-110E"].ratio == 161.0 and "ratio" in catalogue["RV-110E"].assumed


def test_wrong_tooth_number_is_a_one_line_config_error(write, reducers_text):
    path = write("reducers.toml", reducers_text.replace("input_gear_teeth = 10\n", "input_gear_teeth = 11\n", 1))
    with pytest.raises(ConfigError) as exc:
        load_reducer_catalogue(path)
    message = str(exc.value)
    assert "\n" not in message and "reducers.RV-110E" in message and "ratio" in message
    path = write("reducers.toml", reducers_text.replace('{ component = "pin_ring",', '{ component = "pins",', 1))
    with pytest.raises(ConfigError, match="unknown rv component 'pins'"):
        load_reducer_catalogue(path)

"""Strict compensation uploads (issue 22): a closed schema, bands per term type, and the rigidity change an upload
makes to a reference record, judged by pure functions."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tcms_daq.compensation import Compensator
from tcms_daq.compensation.plausibility import (
    CompensationChecks,
    ReferenceLoop,
    judge_upload,
    rigidity_change,
    schema_problems,
    synthetic_reference,
)
from tcms_daq.compensation.terms import Periodic, Scale, Torsion

CHECKS = CompensationChecks()
IDENTITY = Compensator.identity()
REFERENCE = synthetic_reference(IDENTITY, 1000.0, 300.0)


def _periodic_terms(n: int) -> str:
    return "".join(f'[[terms]]\ntype = "periodic"\nperiod_arcsec = {72.0 / (k + 1):.9g}\nsin_arcsec = 0.5\n'
                   for k in range(n))


@pytest.mark.parametrize(("text", "named"), [
    ('[[compensator.terms]]\ntype = "scale"\ncoefficient = 0.5\n', "'terms'"),  # the table a dropped term hid in
    ('[[terms]]\ntype = "torsion"\narcsec_per_nm = 1e6\n', "torsion: arcsec_per_nm 1e+06"),
    ('[[terms]]\ntype = "torsion"\narcsec_per_nm = -0.9\n', "torsion: arcsec_per_nm -0.9"),
    (_periodic_terms(10_000), "10000 terms"),
    ('[compensator]\ndescripton = "typo"\n', "'descripton'"),
    ('[tems]\n', "'tems'"),
    ('[[terms]]\ntype = "scale"\ncoefficient = 0.01\ncoeficient = 0.02\n', "'coeficient'"),
    ('[[terms]]\ntype = "scale"\ncoefficient = 0.01\n[terms.uncertainty]\nbogus = 1.0\n', "'bogus'"),
    ('[[terms]]\ntype = "periodic"\nperiod_arcsec = 72.0\nsin_arcsec = 500.0\n', "amplitude 500"),
    ('[[terms]]\ntype = "periodic"\nperiod_arcsec = 0.01\nsin_arcsec = 0.1\n', "period 0.01"),
    ('[[terms]]\ntype = "scale"\ncoefficient = 0.5\n', "scale: coefficient 0.5"),
    ('[[terms]]\ntype = "offset"\nvalue_arcsec = 1e5\n', "value_arcsec 100000"),
])
def test_each_implausible_upload_is_named_in_one_line(text, named):
    judgement = judge_upload(text, IDENTITY, REFERENCE, CHECKS)
    reason = judgement.reason()
    assert judgement.problems and named in reason and "\n" not in reason


def test_the_schema_check_names_unknown_tables_before_building_anything():
    problems = schema_problems({"compensator": {"terms": [{"type": "scale", "coefficient": 0.5}]}})
    assert problems == ["[compensator]: unknown key 'terms' (allowed: delta_l_mm, description, k, n_points, "
                        "phi_rad, source, tolerance_arcsec)"]
    assert schema_problems({"structure": {}, "parts": {}, "extra": 1}) == [
        "geometry file: unknown key 'extra' (allowed: model, parts, structure)"]
    # what the compensator itself writes passes its own schema
    import tomllib

    written = Compensator([Scale(0.01), Torsion(0.004), Periodic(72.0, 0.3, 0.1)],
                          meta={"description": "x", "source": "y"}).to_toml()
    assert schema_problems(tomllib.loads(written)) == []


def test_rigidity_change_follows_the_physics_of_a_scale_and_a_torsion_term():
    """A scale coefficient c multiplies every compensated angle by (1 − c): the rigidity by 1/(1 − c). A torsion
    term of c_T ″/N·m subtracts c_T from the compliance 60/K ″/N·m."""
    scale = Compensator([Scale(0.02)])
    assert rigidity_change(IDENTITY, scale, REFERENCE) == pytest.approx(1 / 0.98 - 1, rel=1e-6)
    torsion = Compensator([Torsion(0.01)])
    compliance = 60.0 / 300.0
    assert rigidity_change(IDENTITY, torsion, REFERENCE) == pytest.approx(compliance / (compliance - 0.01) - 1,
                                                                          rel=1e-6)
    assert rigidity_change(scale, scale, REFERENCE) == pytest.approx(0.0, abs=1e-12)


def test_a_large_rigidity_change_is_refused_and_a_small_one_accepted():
    small = judge_upload('[[terms]]\ntype = "scale"\ncoefficient = 0.02\n', IDENTITY, REFERENCE, CHECKS)
    assert not small.problems and not small.refused and small.rigidity_change == pytest.approx(0.0204, rel=1e-2)
    large = judge_upload('[[terms]]\ntype = "torsion"\narcsec_per_nm = 0.05\n', IDENTITY, REFERENCE, CHECKS)
    assert not large.problems and "+33.3%" in large.refused and "force=true" in large.refused
    assert large.reason() == large.refused


def test_a_reference_run_is_read_from_its_raw_columns():
    t = np.linspace(0, 10, 5000)
    torque = 800.0 * np.sin(2 * math.pi * t / 5)
    enc = torque / 300.0 * 60.0 + 5.0 * np.sign(np.cos(2 * math.pi * t / 5))  # a loop with friction
    ref = ReferenceLoop.from_columns({"time_s": t, "torque_nm": torque, "encoder_arcsec": enc}, "run r1")
    assert ref is not None and ref.source == "run r1"
    change = rigidity_change(IDENTITY, Compensator([Scale(-0.03)]), ref)
    assert change == pytest.approx(1 / 1.03 - 1, rel=1e-6)
    assert ReferenceLoop.from_columns({"time_s": t, "torque_nm": torque}, "no encoder") is None

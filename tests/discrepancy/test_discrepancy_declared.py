"""A user adds an effect without editing the core: a declared form (one parameter × a column of the design)
registered in code or through an entry point of ``tcms_daq.effects``; it is then a candidate like the built-in
ones. Data from a generator of its own (a spring that stiffens as T·|T|), not from the simulator."""

from __future__ import annotations

import numpy as np
import pytest

from tcms_daq.discrepancy import catalogue as cat
from tcms_daq.discrepancy import effects as fx
from tcms_daq.discrepancy.catalogue import DeclaredEffect, register_effect, unregister_effect
from tcms_daq.discrepancy.model_file import model_from_result, parse_model
from tcms_daq.discrepancy.workflow import run_discrepancy
from tcms_daq.samples import Samples

SOFTENING = DeclaredEffect(
    name="odd_quadratic_softening", parameter="coef_arcsec_per_nm2", unit="″/(N·m)²",
    description="a twist growing as T·|T| (a softening that keeps the sign of the torque)",
    column=lambda data: data.torque_nm * np.abs(data.torque_nm), max_abs=1e-3)


def loops(seed: int, coef: float):
    """±600 N·m triangle loops at 300 N·m/arcmin, 100 Hz, 0.2″ white noise, plus coef·T·|T| in the reading."""
    rng = np.random.default_rng(seed)
    legs, level = [], 0.0
    for rate in (200.0, 600.0):
        for target in [-600.0] + [600.0, -600.0] * 3:
            n = int(abs(target - level) / rate * 100)
            legs.append(np.linspace(level, target, n, endpoint=False))
            level = target
    torque = np.concatenate(legs)
    t = np.arange(len(torque)) / 100.0
    twist = 0.2 * torque
    measured = twist + coef * torque * np.abs(torque) + rng.normal(0, 0.2, len(t))
    return Samples(t, torque, measured), Samples(t, torque, twist)


@pytest.fixture
def declared():
    register_effect(SOFTENING)
    yield SOFTENING
    unregister_effect(SOFTENING.name)


def test_undeclared_it_cannot_be_named():
    """Without the declaration the nearest built-in forms stand in for it (here a cubic stiffness: T·|T| and
    T³ are close on ±600 N·m) — the declared name is not among the candidates."""
    result = run_discrepancy(*loops(1, 4e-6))
    assert "odd_quadratic_softening" not in result.names + [n for a in result.aliases for n in a.names]


def test_declared_it_is_named_with_its_value_and_explained(declared):
    result = run_discrepancy(*loops(1, 4e-6))
    assert result.names == ["odd_quadratic_softening"], result.to_dict()
    value = result.effects[0].parameters["coef_arcsec_per_nm2"]
    assert value == pytest.approx(4e-6, rel=0.10)
    assert result.verdict.verdict == "explained", result.verdict.to_dict()
    model = parse_model(model_from_result(result).to_toml())  # the model file knows it too
    assert model.terms[0].name == "odd_quadratic_softening"


def test_declared_effects_are_checked(declared):
    with pytest.raises(ValueError, match="built-in"):
        register_effect(DeclaredEffect("backlash", "b", "″", "", lambda d: d.torque_nm, 1.0))
    with pytest.raises(ValueError, match="identifiers"):
        register_effect(DeclaredEffect("bad name", "b", "″", "", lambda d: d.torque_nm, 1.0))
    broken = DeclaredEffect("broken", "b", "″", "", lambda d: np.full(3, np.nan), 1.0)
    register_effect(broken)
    try:
        with pytest.raises(ValueError, match="must be .* finite values"):
            run_discrepancy(*loops(2, 0.0), effects=["broken"])
    finally:
        unregister_effect("broken")


def test_an_installed_package_declares_one_through_an_entry_point(monkeypatch):
    class EntryPoint:
        name = "softening"

        def load(self):
            return SOFTENING

    monkeypatch.setattr("importlib.metadata.entry_points",
                        lambda group: [EntryPoint()] if group == cat.ENTRY_POINT_GROUP else [])
    monkeypatch.setattr(fx, "_ENTRY_POINTS_LOADED", False)
    try:
        result = run_discrepancy(*loops(3, 4e-6))
        assert result.names == ["odd_quadratic_softening"]
    finally:
        unregister_effect(SOFTENING.name)

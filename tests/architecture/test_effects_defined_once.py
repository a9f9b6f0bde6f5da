"""Each effect is defined once: its name is written (as a string) only in ``tcms_daq/discrepancy/effects.py``, where
it is registered, through the same call a user's effect goes through; every other module of the installed package
refers to it through the registry or the name constants. The simulator hides an effect with the same definition's
streaming form."""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest

from tcms_daq.discrepancy import effects as fx

ROOT = Path(__file__).resolve().parents[2]
DEFINED_IN = Path("tcms_daq/discrepancy/effects.py")
# The same word naming something else: the loop's measured backlash (a headline result and its label) and the
# compensator's own term type (compensation.terms registry), not the discrepancy effects.
OTHER_MEANINGS = {
    (Path("tcms_daq/analysis/evaluation.py"), fx.BACKLASH),
    (Path("tcms_daq/analysis/report.py"), fx.BACKLASH),
    (Path("tcms_daq/identity.py"), fx.BACKLASH),
    (Path("tcms_daq/service/messages.py"), fx.BACKLASH),  # the fleet page's column label of the measured backlash
    (Path("tcms_daq/compensation/terms.py"), fx.THERMAL_DRIFT),
}


def _string_constants(path: Path) -> list[tuple[str, int]]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    return [(node.value, node.lineno) for node in ast.walk(tree)
            if isinstance(node, ast.Constant) and isinstance(node.value, str)]


def test_each_built_in_effect_name_is_written_once():
    assert len(fx.BUILT_IN) == len(set(fx.BUILT_IN)) >= 10
    names = set(fx.BUILT_IN)
    found: dict[str, list[str]] = {n: [] for n in names}
    for folder in ("tcms_daq", "sim", "drivers"):
        for path in sorted((ROOT / folder).rglob("*.py")):
            rel = path.relative_to(ROOT)
            for value, line in _string_constants(path):
                if value in names and (rel, value) not in OTHER_MEANINGS:
                    found[value].append(f"{rel}:{line}")
    for name, places in found.items():
        assert places and all(p.startswith(f"{DEFINED_IN}:") for p in places), (name, places)
        assert len(places) == 1, (name, places)


def test_built_ins_go_through_the_registration_users_use():
    for name in fx.BUILT_IN:
        with pytest.raises(ValueError, match="built-in"):
            fx.register_effect(fx.REGISTRY[name])
    assert list(fx.REGISTRY)[: len(fx.BUILT_IN)] == list(fx.BUILT_IN) == fx.EFFECT_NAMES[: len(fx.BUILT_IN)]


def test_the_simulator_hides_an_effect_with_the_formula_that_identifies_it():
    """A batch through the simulator's hook adds exactly the effect's formula on the batch's signals."""
    from tcms_daq.sim.effects import EffectsHook, effects_from_table

    n = 400
    t = np.linspace(0.0, 8.0, n)
    applied = 600.0 * np.sin(2 * np.pi * t / 4.0)
    angle = applied / 5.0 + 3.0
    cols = {"time_s": t, "applied_torque_nm": applied, "torque_signal_nm": applied.copy(),
            "angle_signal_arcsec": angle, "true_angle_arcsec": angle}
    for name in fx.BUILT_IN:
        effect = fx.REGISTRY[name]
        if effect.fixed_gain:
            continue
        hook = EffectsHook(effects_from_table({name: dict(effect.typical)}))
        added = hook(dict(cols))["angle_signal_arcsec"] - angle
        direction = np.where(np.diff(applied, prepend=applied[0]) >= 0, 1.0, -1.0)  # rising: loading
        signals = fx.BatchSignals(t - t[0], applied, angle, direction, np.full(n, 1 / 5.0))
        expected = effect.formula(signals, effect.typical)
        inner = slice(2, -2)  # the slope's one-sided ends
        np.testing.assert_allclose(added[inner], expected[inner], atol=1e-6 * (1 + np.abs(expected).max()),
                                   err_msg=name)

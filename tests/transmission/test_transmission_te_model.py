"""The discrepancy workflow on the transmission error: a hidden order at a component's order is named (order
within 1 %, amplitude within 10 %), applied, and the next run is ``consistent``; an order of no component is
``unexplained`` with its order and no name — on the simulator and on the independent generator
(``sim/te_independent.py``: its own physics, phase convention, quantised encoders, speed ripple in time). The model
file round-trips."""

from __future__ import annotations

import math

import pytest
from tcms_daq.sim.station_trials import FAMILIES, run_trial

from tcms_daq.errors import DataFormatError
from tcms_daq.transmission.te import TeLine
from tcms_daq.transmission.te_model import (
    TeComparison,
    TeFinding,
    TeHarmonicTerm,
    TeModel,
    apply_findings,
    parse_te_model,
)


@pytest.mark.parametrize(("family", "seed"), [("sim-rv110e", 1), ("sim-hfuc32", 2), ("indep-rv", 3), ("indep-hd", 4)])
def test_hidden_order_named_applied_and_closed(family, seed):
    trial = FAMILIES[family](seed)
    order, amplitude, label = trial.hidden
    outcome = run_trial(trial)
    assert outcome["verdict_1"] == "explained", outcome
    assert outcome["named"], outcome  # order within 1 %, amplitude within 10 %, the component, nothing else
    found = [g for g in outcome["gaps_1"] if abs(g[0] - order) <= 0.01 * order]
    assert found and label in found[0][2]
    assert outcome["verdict_2"] == "consistent", outcome


def test_an_order_of_no_component_is_unexplained_with_its_order():
    trial = FAMILIES["indep-rv-foreign"](5)
    order = trial.hidden[0]
    outcome = run_trial(trial)
    assert outcome["verdict_1"] == "unexplained", outcome
    assert outcome["unexplained"], outcome
    (gap,) = outcome["gaps_1"]
    assert gap[0] == pytest.approx(order, rel=0.01) and gap[2] is None


def test_nothing_hidden_is_consistent():
    outcome = run_trial(FAMILIES["indep-rv-null"](6))
    assert outcome["quiet"], outcome


def test_model_file_round_trip_and_a_correction_adds_as_a_vector():
    model = TeModel(161.0, (TeHarmonicTerm(39.0, 3.0, 110.0, "pin_ring", "catalogue"),), "RV-110E")
    again = parse_te_model(model.to_toml())
    assert again == model
    # the residual at order 39 is 1″ at 110° + 180°: the model's 3″ becomes 2″ at 110°
    line = TeLine(39.0, 1.0, 290.0, 0.01, 0.5, 0.001, ("pin_ring",))
    comparison = TeComparison("explained", [TeFinding(line, 39.0)], {}, 0.0, 0.0, 1)
    new = apply_findings(model, comparison, source="run 7")
    (h,) = new.harmonics
    assert (h.amplitude_arcsec, h.phase_deg % 360) == (pytest.approx(2.0), pytest.approx(110.0))
    assert new.version == 2 and "run 7" in h.source
    assert new.predict_arcsec(0.0) == pytest.approx(2.0 * math.sin(math.radians(110.0)))
    with pytest.raises(DataFormatError, match="format must be"):
        parse_te_model('format = "x"\nratio = 1.0\n')
    with pytest.raises(DataFormatError, match=r"harmonics\[0\]"):
        parse_te_model('format = "tcms-te-model/1"\nratio = 161.0\n[[harmonics]]\norder = -1.0\namplitude_arcsec = 1.0\n')

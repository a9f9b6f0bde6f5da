"""The closed loop on the bench's own effects: every effect the simulated bench can hide, at two sizes a user
would meet (½ and 1 × its typical size), run 1 → discrepancy → apply (the model file with the fitted parameters and
their uncertainties) → run 2 on new data (another seed, a smaller amplitude) analysed against the applied model
ends ``consistent`` with nothing named. (The service path does the same through its bench model versions:
tests/service/test_service_discrepancy.py.)"""

from __future__ import annotations

import pytest
from tcms_daq.sim.trials import CASES, closed_loop

from tcms_daq.discrepancy import effects as fx

SINGLE = [c for c in CASES if c in fx.REGISTRY]


@pytest.mark.parametrize("size", [0.5, 1.0])
@pytest.mark.parametrize("case", SINGLE)
def test_apply_closes_the_loop(case, size):
    loop = closed_loop(case, size, seed=31)
    assert list(loop.named) == [case], loop.to_dict()
    primary = fx.REGISTRY[case].primary
    assert loop.uncertainty[case][primary] > 0, loop.to_dict()  # the uncertainty travels with the model
    assert loop.closed, loop.to_dict()


def test_every_effect_the_simulator_hides_is_a_case():
    assert sorted(SINGLE) == sorted(n for n, e in fx.REGISTRY.items() if e.simulated)

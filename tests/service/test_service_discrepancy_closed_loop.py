"""The closed loop over the service, for the effects the simulated bench can hide, at ½ and 1 × each one's typical
size: POST /api/tests on a bench with the effect in [sim.effects] → POST /api/discrepancy → POST
/api/discrepancy/{id}/apply (the model file with the fitted parameters and their uncertainties becomes the bench
model's next version) → a second POST /api/tests (new data, ±600 N·m instead of ±800) → its analysis against that
version is ``consistent`` with nothing named. The loop is ``sim.trials.closed_loop`` (the in-process loop's code)
on a ``ServiceRig``; each case has its own service.

CLOSED lists the (effect, size) pairs that closed every time they were measured (twice or more) with ``python -m
tcms_daq.service.closed_loop --closed-loop SIZE --first-seed 31 --case EFFECT``; the README's table shows all 20. Nine
more closed in one measurement and not in another (run 2 on a loaded machine varies: 0.26–0.52″ held-out RMS
against a 0.20″ floor when it does not close; the cause is not found yet), so they are not held here.
"""

from __future__ import annotations

import pytest
from tcms_daq.sim.trials import CASES, closed_loop

from tcms_daq.discrepancy import effects as fx
from tcms_daq.service.closed_loop import service_rig

SINGLE = [c for c in CASES if c in fx.REGISTRY]

CLOSED: list[tuple[str, float]] = [
    (fx.TIME_SKEW, 0.5), (fx.THERMAL_DRIFT, 0.5), (fx.BENDING_DEFORMATION, 0.5), (fx.TORSION_OFFSET, 0.5),
    (fx.INTERPOLATION_ERROR, 0.5), (fx.PERIODIC_ERROR, 0.5),
]


@pytest.mark.slow
@pytest.mark.timeout(900)
@pytest.mark.parametrize(("case", "size"), CLOSED)
def test_the_service_closes_the_loop(case, size):
    loop = closed_loop(case, size, seed=31, rig=service_rig())
    assert list(loop.named) == [case], loop.to_dict()
    primary = fx.REGISTRY[case].primary
    assert loop.uncertainty[case][primary] > 0, loop.to_dict()  # the uncertainty travels into the bench model
    assert loop.apply_refused is None, loop.to_dict()
    assert loop.closed, loop.to_dict()


def test_the_closed_cases_are_effects_the_bench_hides():
    assert {case for case, _ in CLOSED} <= set(SINGLE)
    assert all(size in (0.5, 1.0) for _, size in CLOSED)

"""The closed loop over the service, for the effects the simulated bench can hide, at ½ and 1 × each one's typical
size: POST /api/tests on a bench with the effect in [sim.effects] → POST /api/discrepancy → POST
/api/discrepancy/{id}/apply (the model file with the fitted parameters and their uncertainties becomes the bench
model's next version) → a second POST /api/tests (new data, ±600 N·m instead of ±800) → its analysis against that
version is ``consistent`` with nothing named. The loop is ``sim.trials.closed_loop`` (the in-process loop's code)
on a ``ServiceRig``; each case has its own service.

CLOSED lists the (effect, size) pairs measured to close with ``python -m tcms_daq.sim.trials --closed-loop SIZE
--service --first-seed 31 --case EFFECT`` (the README's table); the others are in that table with what run 2 said.
"""

from __future__ import annotations

import pytest
from tcms_daq.sim.trials import CASES, closed_loop
from tcms_daq.sim.trials_service import service_rig

from tcms_daq.discrepancy import effects as fx

SINGLE = [c for c in CASES if c in fx.REGISTRY]

CLOSED: list[tuple[str, float]] = [
    (fx.TIME_SKEW, 0.5), (fx.TIME_SKEW, 1.0), (fx.THERMAL_DRIFT, 0.5),
    (fx.BENDING_DEFORMATION, 0.5), (fx.BENDING_DEFORMATION, 1.0), (fx.TORSION_OFFSET, 0.5), (fx.TORSION_OFFSET, 1.0),
    (fx.SCALE_ERROR, 0.5), (fx.SCALE_ERROR, 1.0), (fx.INTERPOLATION_ERROR, 0.5), (fx.INTERPOLATION_ERROR, 1.0),
    (fx.PERIODIC_ERROR, 0.5), (fx.PERIODIC_ERROR, 1.0), (fx.BACKLASH, 0.5), (fx.NONLINEAR_STIFFNESS, 1.0),
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

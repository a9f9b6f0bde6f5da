"""Coarse sampling (issue 23): a run recorded with fewer samples (a protocol run under CPU load) is read between
samples farther apart; the interpolation error at that spacing is a budget line, so the thinned run's result stays
within U of the full one. The records come from the validation generator (benchmarks/coverage: physics, not the
evaluation), 1 kHz, Dahl friction, soft lost-motion zone, the declared noise; thinned to every 5th and 20th sample."""

from __future__ import annotations

import math

import numpy as np
import pytest

from benchmarks.coverage import declared_chain
from benchmarks.coverage.families import Family, draw_run
from tcms_daq.analysis.evaluation import EvaluationSettings
from tcms_daq.procedure.evaluation import evaluate_test
from tcms_daq.uncertainty.budget import SAMPLING_LINE

FAMILY = Family("thinning", "RV", "dahl", "soft", False, 1000.0, 0.0, False, (1.0, 1.0))
QUANTITIES = ("rigidity_nm_per_arcmin", "lost_motion_arcsec", "backlash_arcsec")
RUNS = 4


@pytest.fixture(scope="module")
def runs():
    rng = np.random.default_rng(11)
    chain = declared_chain()
    out = []
    for _ in range(RUNS):
        record, reducer = draw_run(FAMILY, rng)
        settings = EvaluationSettings(rated_torque_nm=reducer.rated_torque_nm)
        full = evaluate_test(record.time_s, record.torque_nm, record.angle_arcsec, settings, chain=chain)
        thinned = {step: evaluate_test(record.time_s[::step], record.torque_nm[::step], record.angle_arcsec[::step],
                                       settings, chain=chain) for step in (5, 20)}
        out.append((full, thinned))
    return out


@pytest.mark.parametrize("step", [5, 20])
def test_a_thinned_run_stays_within_u_of_the_full_one(runs, step):
    for full, thinned in runs:
        ev = thinned[step]
        for q in QUANTITIES:
            diff = ev.uncertainty[q]["value"] - full.uncertainty[q]["value"]
            allowed = math.hypot(ev.uncertainty[q]["U"], full.uncertainty[q]["U"])
            assert abs(diff) <= allowed, (step, q, diff, allowed, ev.uncertainty[q]["budget"])


def test_the_budget_names_the_sampling_line_and_it_grows_with_the_spacing(runs):
    for full, thinned in runs:
        lines = {step: {b["source"]: b["contribution"] for b in thinned[step].uncertainty["lost_motion_arcsec"]["budget"]}
                 for step in (5, 20)}
        assert lines[20].get(SAMPLING_LINE, 0.0) > 0.0, lines[20]
        assert lines[20][SAMPLING_LINE] > lines[5].get(SAMPLING_LINE, 0.0)
        assert full.interpolation_u["lost_motion_arcsec"] <= thinned[20].interpolation_u["lost_motion_arcsec"]

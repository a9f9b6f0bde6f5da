"""The bench runner over the in-process simulated bench, without HTTP."""

from __future__ import annotations

import threading

from tcms_daq.service import schemas
from tcms_daq.service.runner import BenchRunner


def test_a_batch_that_does_not_reach_the_store_fails_the_run(sim_config):
    runner = BenchRunner.from_config(sim_config, sim_speed=50.0)
    live_batches = []
    runner.open(live_batches.append)
    try:
        plan = runner.plan(schemas.TestRequest(reducer="RV-110E", max_torque_nm=300, cycles=1, rate_nm_per_s=300))
        written, phases = [], []

        def record(columns):
            if len(written) == 3:
                raise OSError("disk full")
            written.append(columns)

        outcome = runner.execute(plan, run_id="r1", record=record, on_phase=lambda p, **_: phases.append(p),
                                 abort=threading.Event())
    finally:
        runner.close()
    assert outcome.status == "failed" and outcome.error == "recording failed: store-r1: OSError: disk full"
    assert len(written) == 3 and "evaluating" in phases  # the run itself went on to its end
    assert live_batches and set(live_batches[0]) == set(runner.channels)

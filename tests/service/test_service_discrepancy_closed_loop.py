"""The closed loop over the service (``tcms_daq.service.closed_loop``): ``sim.trials.closed_loop`` on a
``ServiceRig`` — POST /api/tests on a bench with the effect in [sim.effects] → POST /api/discrepancy → POST
/api/discrepancy/{id}/apply → a second POST /api/tests → its analysis against the new bench model version.

Measured with ``python -m tcms_daq.service.closed_loop --closed-loop 0.5 --closed-loop 1 --first-seed 31 --case NAME``
(the README's table): 15 of 20 closed in one pass, but run 2 of cases that closed before sometimes ends
``unexplained`` with about 0.5″ held-out RMS against a 0.20″ floor (interpolation ½ ×, torsion 1 ×, scale 1 ×,
thermal drift 1 ×, backlash 1 ×), the cause not found yet; so no case is held here as closing. What is held: the rig
builds the request of a trial design and the bench it runs on.
"""

from __future__ import annotations

import tomllib

from tcms_daq.sim.trials import SECOND_RUN, TrialDesign

from tcms_daq.service import schemas
from tcms_daq.service.closed_loop import bench_config_with_effects, programme_s, request_of


def test_the_rig_runs_the_trial_design_as_a_request(tmp_path):
    body = request_of(TrialDesign())
    assert body == {"reducer": "RV-110E", "max_torque_nm": 800.0, "cycles": 3, "profile": "continuous",
                    "rates": [200.0, 600.0]}
    schemas.TestRequest.model_validate(body)  # the service accepts it
    # ±800 N·m: to −A, 3 loops (4 A each) and back, at each rate
    assert programme_s(TrialDesign()) == sum(800.0 * 14 / r for r in (200.0, 600.0))
    assert programme_s(SECOND_RUN) < programme_s(TrialDesign())
    config = tomllib.loads(bench_config_with_effects(tmp_path, {"backlash": {"backlash_arcsec": 2.0}}, seed=7,
                                                     sample_rate_hz=50.0).read_text(encoding="utf-8"))
    assert config["sim"]["effects"] == {"backlash": {"backlash_arcsec": 2.0}}
    assert config["sim"]["seed"] == 7 and config["sim"]["sample_rate_hz"] == 50.0

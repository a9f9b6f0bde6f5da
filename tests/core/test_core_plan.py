"""Tests at several output positions and loading rates (tcms run --positions / --rates) on the in-process
simulated bench with the rich reducer model: each position's and each rate's evaluation recovers the simulated
truth where the truths differ; the plan's bounds; the compensation over a full revolution of the output."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from tcms_daq.cli import main
from tcms_daq.config import load_bench_config
from tcms_daq.procedure.evaluation import rate_sensitivity
from tcms_daq.procedure.plan import build_plan, positions_from, rates_from

RICH = ("--set", "sim.model=rich")


def _run_json(capsys, *argv: str) -> dict:
    assert main(["run", *argv, "--json"]) == 0
    out, err = capsys.readouterr()
    assert err == ""
    return json.loads(out)


def _spread(values) -> float:
    return max(values) - min(values)


def test_positions_recover_the_truth_per_position(capsys):
    res = _run_json(capsys, "--positions", "4", *RICH)
    entries = res["positions"]
    assert [e["position_deg"] for e in entries] == [0.0, 90.0, 180.0, 270.0]
    truths = [e["truth"] for e in entries]
    # the truths differ between the positions by far more than the tolerances
    assert _spread([t["rigidity_nm_per_arcmin"] for t in truths]) > 0.03 * truths[0]["rigidity_nm_per_arcmin"]
    assert _spread([t["lost_motion_arcsec"] for t in truths]) > 2.0
    for e, t in zip(entries, truths, strict=True):
        assert e["rigidity_nm_per_arcmin"] == pytest.approx(t["rigidity_nm_per_arcmin"], rel=0.01)
        assert e["lost_motion_arcsec"] == pytest.approx(t["lost_motion_arcsec"], abs=0.5)
        assert e["backlash_arcsec"] == pytest.approx(t["backlash_arcsec"], abs=1.0)
        # asymmetric stiffness: the positive side is stiffer, as simulated
        assert e["positive_rigidity_nm_per_arcmin"] > 1.05 * e["negative_rigidity_nm_per_arcmin"]
    lost = [e["lost_motion_arcsec"] for e in entries]
    rigidity = [e["rigidity_nm_per_arcmin"] for e in entries]
    assert res["lost_motion_arcsec_max"] == max(lost) == res["lost_motion_arcsec"]  # GB/T 40731: the maximum
    assert res["lost_motion_arcsec_spread"] == pytest.approx(max(lost) - min(lost))
    assert res["rigidity_nm_per_arcmin"] == min(rigidity) == res["rigidity_nm_per_arcmin_min"]
    assert res["truth"]["lost_motion_arcsec"] == max(t["lost_motion_arcsec"] for t in truths)
    assert res["profile"]["plan"] == "positions" and len(res["profile"]["stages"]) == 4
    assert {lp["stage"] for lp in res["loops"]} == {1, 2, 3, 4}


def test_rates_recover_the_truth_per_rate(capsys):
    res = _run_json(capsys, "--rates", "50,500", *RICH)
    slow, fast = res["rates"]
    assert (slow["rate_nm_per_s"], fast["rate_nm_per_s"]) == (50.0, 500.0)
    # creep follows a slow loop (softer), viscous friction widens a fast one
    assert fast["truth"]["rigidity_nm_per_arcmin"] > 1.02 * slow["truth"]["rigidity_nm_per_arcmin"]
    assert fast["truth"]["backlash_arcsec"] > slow["truth"]["backlash_arcsec"] + 3.0
    for e in (slow, fast):
        assert e["rigidity_nm_per_arcmin"] == pytest.approx(e["truth"]["rigidity_nm_per_arcmin"], rel=0.01)
        assert e["lost_motion_arcsec"] == pytest.approx(e["truth"]["lost_motion_arcsec"], abs=0.5)
        assert e["loading_rate_nm_per_s"] == pytest.approx(e["rate_nm_per_s"], rel=0.05)
    sensitivity = res["rate_sensitivity"]["rigidity_nm_per_arcmin_per_decade"]  # one decade between the rates
    assert sensitivity == pytest.approx(fast["rigidity_nm_per_arcmin"] - slow["rigidity_nm_per_arcmin"])
    truth_sensitivity = fast["truth"]["rigidity_nm_per_arcmin"] - slow["truth"]["rigidity_nm_per_arcmin"]
    assert sensitivity == pytest.approx(truth_sensitivity, abs=0.02 * slow["truth"]["rigidity_nm_per_arcmin"])


def test_compensation_holds_over_a_full_revolution(capsys):
    """The paper's measuring-chain geometry (periodic terms over the revolution): compensated, every position
    recovers its truth; the raw encoder does not."""
    paper = ("--set", "sim.geometry=geometry-paper.toml", "--set", "bench.compensation=geometry-paper.toml")
    res = _run_json(capsys, "--positions", "4", "--cycles", "1", *RICH, *paper)
    raw = _run_json(capsys, "--positions", "4", "--cycles", "1", *RICH, *paper, "--no-compensation")
    for e, r in zip(res["positions"], raw["positions"], strict=True):
        truth = e["truth"]["rigidity_nm_per_arcmin"]
        assert e["rigidity_nm_per_arcmin"] == pytest.approx(truth, rel=0.01)
        assert e["lost_motion_arcsec"] == pytest.approx(e["truth"]["lost_motion_arcsec"], abs=0.5)
        assert abs(r["rigidity_nm_per_arcmin"] - truth) > 0.05 * truth


def test_positions_as_a_list_and_the_simple_model(capsys):
    """The simple model is the same at every position: the per-position results agree with its one truth."""
    res = _run_json(capsys, "--positions", "10,100", "--max-torque", "500", "--cycles", "1")
    assert [e["position_deg"] for e in res["positions"]] == [10.0, 100.0]
    for e in res["positions"]:
        assert e["truth"]["rigidity_nm_per_arcmin"] == res["positions"][0]["truth"]["rigidity_nm_per_arcmin"]
        assert e["rigidity_nm_per_arcmin"] == pytest.approx(e["truth"]["rigidity_nm_per_arcmin"], rel=0.01)


@pytest.mark.parametrize(("argv", "message"), [
    (["--positions", "0"], "positions must be 1…36"),
    (["--positions", "10,360"], "[0, 360)"),
    (["--positions", "10,nan"], "finite"),
    (["--positions", "10,10"], "repeated"),
    (["--rates", "50,inf"], "finite"),
    (["--rates", ",".join(str(10 * i) for i in range(1, 12))], "1…10"),
    (["--rates", "50,500", "--positions", "4"], "cannot be combined"),
    (["--rates", "50,500", "--rate", "50"], "exclude each other"),
    (["--rates", "0.01,50"], "slowest rate"),
])
def test_bad_plans_exit_2_with_one_line(capsys, argv, message):
    try:
        code = main(["run", *argv])
    except SystemExit as exc:  # argparse's own errors: the usage, then one line
        code = exc.code
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert message in err[-1] and "Traceback" not in "".join(err)


def test_plan_bounds_and_helpers():
    assert positions_from(3) == [0.0, 120.0, 240.0]
    with pytest.raises(ValueError, match="count or a list"):
        positions_from(True)  # type: ignore[arg-type]
    assert rates_from([5, 50.0]) == [5.0, 50.0]
    cfg = load_bench_config()
    test = cfg.procedure.model_copy(update={"max_torque_nm": 500.0})
    plan = build_plan(test, None, cfg.bench, positions=4)
    moves = [step for _, step in plan.steps() if not hasattr(step, "target_nm")]
    assert [m.position_deg for m in moves] == [0.0, 90.0, 180.0, 270.0]
    # planned time: four whole profiles plus three 90° moves at 30 °/s (+ settle per move)
    profile_s = plan.first.duration_s()
    assert plan.duration_s() == pytest.approx(4 * profile_s + 3 * 3.0 + 4 * 0.5)
    short = cfg.bench.model_copy(update={"max_test_duration_s": 2.5 * profile_s})
    with pytest.raises(ValueError, match="longest test"):
        build_plan(test, None, short, positions=4)
    # the sensitivity is the least-squares slope against log10(rate), computed here independently
    rates, values = [10.0, 100.0, 1000.0], [100.0, 103.0, 105.0]
    x = np.log10(rates)
    slope = np.polyfit(x, values, 1)[0]
    assert rate_sensitivity(rates, values) == pytest.approx(slope)
    assert rate_sensitivity([10.0], [1.0]) is None
    assert math.isclose(rate_sensitivity([1.0, 10.0], [0.0, 2.0]) or 0.0, 2.0)

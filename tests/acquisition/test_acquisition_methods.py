"""The turning tests (issue 28) through `tcms run --method` on the in-process simulated station
(config/bench-station.toml: the second axis turns the core's unit, sim/instruments/drivetrain.py UnitDriveTrain):
for RV-110E and HFUC-32-100 every result of each method lies within its U of the simulated unit's exact truth, and
the transmission error finds the unit's orders with their components and nothing else (beyond its U of nothing). A bench without the second
axis refuses a turning method naming what it lacks; the input drive's fault and its lost link end a run aborted,
with the input stopped (or left to its watchdog), and an operator's abort stops it too."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from tcms_daq.acquisition import compose_bench
from tcms_daq.acquisition.methodrun import MethodRun
from tcms_daq.cli import main
from tcms_daq.config import load_bench_config, load_reducers_for
from tcms_daq.procedure.plan import PlanRequest, plan_from_request

STATION = "bench-station.toml"
# short programmes (the methods' defaults are longer): one breakaway a direction, two speeds
METHODS = [("transmission-error", ()), ("starting-torque", ("--ramps", "1")),
           ("no-load-torque", ("--speeds", "500,2000")), ("efficiency", ())]


def run_json(capsys, *argv: str) -> dict:
    code = main(["run", *argv, "--json"])
    out, err = capsys.readouterr()
    assert code == 0, err
    return json.loads(out)


@pytest.mark.parametrize("reducer", ["RV-110E", "HFUC-32-100"])
@pytest.mark.parametrize(("method", "args"), METHODS, ids=[m for m, _ in METHODS])
def test_each_method_within_u_of_the_simulated_truth(capsys, reducer, method, args):
    out = run_json(capsys, "--config", STATION, "--reducer", reducer, "--method", method, *args)
    truth, table = out["truth"], out["uncertainty"]
    assert truth and set(out["within_u"]) == set(truth)
    off = {k: (table[k]["value"] if k in table else None, truth[k], table[k]["U"] if k in table else None)
           for k, ok in out["within_u"].items() if not ok}
    assert not off, off  # (value, truth, U) of every result outside its U
    assert out["method"] == method and not out["warnings"], out["warnings"]
    if method == "transmission-error":
        # the unit's orders, each named by its component, and no line it does not have
        catalogue = load_reducers_for(load_bench_config(STATION))
        spec = catalogue[reducer]
        from tcms_daq.transmission.kinematics import component_orders_per_output_rev

        orders = component_orders_per_output_rev(spec.kinematics.teeth(spec.kind))
        expected = {round(h.harmonic * orders[h.component], 3): h.component if h.harmonic == 1 else
                    f"{h.component} {h.harmonic}×" for h in spec.sim.transmission.harmonics}
        found = {round(ln["order"]): ln["components"] for ln in out["te_orders"]}
        assert set(found) >= {round(k) for k in expected}, (found, expected)
        for k, component in expected.items():
            assert component in found[round(k)], (k, component, found)
        # a line at an order the unit has not is noise that passed the pursuit's 1 % false alarm: within its U of 0
        for ln in out["te_orders"]:
            if round(ln["order"]) not in {round(k) for k in expected}:
                entry = table[f"te_order_{ln['order']:.4g}_amplitude_arcsec"]
                assert entry["value"] <= entry["U"], (ln, entry["U"])
        assert all(math.isfinite(v) for v in out["te_curve"]["forward"]["te_arcsec"])
        assert len(out["te_spectrum"]["reverse"]["order"]) == len(out["te_spectrum"]["reverse"]["amplitude_arcsec"])


def test_a_bench_without_the_second_axis_refuses_a_method_naming_what_it_lacks(capsys):
    code = main(["run", "--method", "transmission-error"])
    _, err = capsys.readouterr()
    assert code != 0
    assert "transmission-error needs [instruments.input_drive]" in err and "[instruments.input_angle]" in err, err


def _te_run(*, at_s: float, fault) -> tuple:
    """A transmission-error run on the in-process station with ``fault(virtual bench)`` at ``at_s`` of its clock."""
    cfg = load_bench_config(STATION)
    planned = plan_from_request(PlanRequest(reducer="HFUC-32-100", method="transmission-error"), cfg,
                                load_reducers_for(cfg))
    bench = compose_bench(cfg, config_dir=Path(cfg.source_path).parent)
    vbench = bench.angle.bench  # type: ignore[attr-defined]
    vbench.at(at_s, lambda: fault(vbench))
    run = MethodRun(bench, planned.method_plan, reducer_torque_limit_nm=planned.reducer_torque_limit_nm)
    return run.run(), vbench


@pytest.mark.parametrize(("fault", "interlock", "names", "stopped"), [
    (lambda b: b.second_axis.inject_fault(0x2310), "drive_fault", "0x2310", "FAULT"),
    (lambda b: b.second_axis.lose_link(), "lost_instrument", "input_drive", None),
    (lambda b: setattr(b.faults, "input_angle_muted", True), "stale_data", "input_angle", "SWITCH ON DISABLED"),
], ids=["input-drive-fault", "input-drive-link-lost", "angle-pairs-mute"])
def test_the_second_axis_trips_the_interlocks_and_the_input_stops(fault, interlock, names, stopped):
    record, vbench = _te_run(at_s=3.0, fault=fault)
    assert record.state == "aborted" and record.trip["interlock"] == interlock, (record.state, record.reason)
    assert names in record.reason, record.reason
    drive = vbench.second_axis.drive
    assert drive.velocity_deg_per_s == 0.0 and drive.state != "OPERATION ENABLED", drive.state
    if stopped is not None:  # stopped by the procedure (or in fault); a lost drive is its watchdog's
        assert drive.state == stopped
        assert any(n.startswith("input drive stopped") for n in record.notes), record.notes
    else:
        assert any("its own watchdog" in n for n in record.notes), record.notes
    assert record.loader_final["state"] == "SWITCH ON DISABLED"


def test_an_abort_stops_the_input_before_the_load():
    cfg = load_bench_config(STATION)
    planned = plan_from_request(PlanRequest(reducer="RV-110E", method="efficiency"), cfg, load_reducers_for(cfg))
    bench = compose_bench(cfg, config_dir=Path(cfg.source_path).parent)
    run = MethodRun(bench, planned.method_plan)
    vbench = bench.angle.bench  # type: ignore[attr-defined]
    seen = {}

    def abort():
        seen["velocity"] = vbench.second_axis.drive.velocity_deg_per_s
        seen["torque"] = vbench.applied_torque_nm
        run.abort("operator")

    vbench.at(4.0, abort)  # turning at rated speed against the rated torque
    record = run.run()
    assert record.state == "aborted" and record.reason == "operator"
    assert abs(seen["velocity"]) > 1000 and abs(seen["torque"]) > 500, seen
    assert vbench.second_axis.drive.state == "SWITCH ON DISABLED" and vbench.second_axis.drive.velocity_deg_per_s == 0
    assert record.loader_final["state"] == "SWITCH ON DISABLED" and abs(record.loader_final["torque_actual_nm"]) < 20
    # the input came to rest before the loader's ramp to zero began
    s = record.samples
    rest = s.time_s[(abs(s.extra["input_torque_nm"]) < 8.0) & (s.time_s > 4.0)]
    assert len(rest)

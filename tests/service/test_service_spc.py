"""GET /api/spc/chart and /api/spc/bias over a fleet's runs in one PostgreSQL (generated with a known bench bias)."""

from __future__ import annotations

import numpy as np
import pytest
from svc_helpers import ScriptedRunner, serve

from tcms_daq.service.schemas import SpcChartView
from tcms_daq.store import open_store

BIAS_B = 2.5  # N·m/arcmin: bench line-b reads this much stiffer than line-a


def _fill(url, tmp_path) -> dict[str, float]:
    """Runs of RV-110E on two benches: 4 reference units tested 3 times on each bench, 10 production units on
    line-a alone, then 6 runs on line-a shifted by 6σ (a process change the chart must flag)."""
    rng = np.random.default_rng(5)
    stores = {b: open_store(url, tmp_path, bench_id=b, bench_name=f"bench {b}", recover=False)
              for b in ("line-a", "line-b")}
    n = 0

    def run(bench: str, serial: str, value: float) -> None:
        nonlocal n
        n += 1
        store = stores[bench]
        run_id = f"run-{n:03d}"
        store.create_run(run_id, {"reducer": "RV-110E", "serial_number": serial}, ("time_s",))
        store.set_status(run_id, "completed", results={"rigidity_nm_per_arcmin": value, "backlash_arcsec": 20.0})

    for unit in range(4):
        truth = rng.normal(294.0, 4.0)
        for _ in range(3):
            run("line-a", f"REF-{unit}", truth + rng.normal(0, 0.5))
            run("line-b", f"REF-{unit}", truth + BIAS_B + rng.normal(0, 0.5))
    for unit in range(10):
        run("line-a", f"SN-{unit}", rng.normal(294.0, 0.5))
    for unit in range(6):
        run("line-a", f"SN-late-{unit}", rng.normal(297.0, 0.5))
    stores["line-a"].create_run("run-other", {"reducer": "RV-60N", "serial_number": "X"}, ("time_s",))
    for store in stores.values():
        store.close()
    return {}


def test_spc_chart_and_bias_over_a_shared_store(settings_factory, postgres_url, tmp_path):
    _fill(postgres_url, tmp_path)
    with serve(settings_factory(store_url=postgres_url), runner=ScriptedRunner(bench_id="viewer")) as server:
        c = server.client()
        r = c.get("/api/spc/bias", params={"reducer": "RV-110E", "reference": "line-a"})
        assert r.status_code == 200, r.text
        doc = r.json()
        by = {b["bench"]: b for b in doc["benches"]}
        assert doc["units"] == ["REF-0", "REF-1", "REF-2", "REF-3"] and doc["excluded_runs"] == 16
        assert by["line-a"]["bias"] == 0.0 and by["line-b"]["runs"] == 12
        assert abs(by["line-b"]["bias"] - BIAS_B) <= by["line-b"]["U"] < 1.0
        assert doc["unit"] == "N·m/arcmin" and doc["dof"] == 24 - 5

        chart = c.get("/api/spc/chart", params={"reducer": "RV-110E", "bench": "line-a", "baseline_runs": 22}).json()
        assert SpcChartView.model_validate(chart).model_dump(mode="json") == chart  # the route skips the validation
        values = [p["value"] for p in chart["runs"]]
        assert len(values) == 28 and chart["chart"]["baseline_n"] == 22 and chart["bench"] == "line-a"
        assert [p["serial_number"] for p in chart["runs"]][-1] == "SN-late-5"  # oldest first
        assert chart["chart"]["center"] == pytest.approx(np.mean(values[:22]))
        late = [i for i in chart["chart"]["out_of_control"] if i >= 22]
        assert len(late) >= 4  # the shifted runs are flagged
        fleet = c.get("/api/spc/chart", params={"reducer": "RV-110E", "quantity": "backlash_arcsec"}).json()
        assert len(fleet["runs"]) == 40 and fleet["chart"]["baseline_n"] == 20 and fleet["chart"]["sigma"] == 0.0
        until = chart["runs"][4]["created_at"]
        assert c.get("/api/spc/chart", params={"reducer": "RV-110E", "bench": "line-a", "baseline_until": until}
                     ).json()["chart"]["baseline_n"] == 5

        assert chart["limits"] == "established" and chart["note"] == "baseline of 22 runs"
        assert chart["method"] == "single" and chart["methods"] == {"single": 28}
        few = c.get("/api/spc/chart", params={"reducer": "RV-110E", "bench": "line-a", "baseline_runs": 5}).json()
        assert few["limits"] == "provisional" and few["baseline_n"] == 5 and "provisional until 20" in few["note"]
        none = c.get("/api/spc/chart", params={"reducer": "RV-60N"})
        assert SpcChartView.model_validate(none.json()).model_dump(mode="json") == none.json()
        assert none.status_code == 200 and none.json()["chart"] is None and none.json()["limits"] == "none"
        assert none.json()["note"].startswith("too few runs: 0 completed single runs of RV-60N")

        for path, params, word in (
                ("/api/spc/chart", {"reducer": "RV-110E", "method": "positions"}, "method"),
                ("/api/spc/chart", {"reducer": "RV-110E", "quantity": "torque"}, "quantity"),
                ("/api/spc/chart", {"reducer": "RV-110E", "baseline_runs": 1}, "baseline_runs"),
                ("/api/spc/chart", {"reducer": "RV-110E", "baseline_runs": 5, "baseline_until": until}, "not both"),
                ("/api/spc/chart", {}, "reducer"),
                ("/api/spc/bias", {"reducer": "RV-110E", "reference": "line-z"}, "reference bench 'line-z'"),
                ("/api/spc/bias", {"reducer": "RV-60N"}, "two benches")):
            r = c.get(path, params=params)
            assert r.status_code == 422 and word in r.json()["detail"], (params, r.text)


def test_spc_series_are_per_test_method(settings_factory, tmp_path):
    """4-position tests (the worst of 4: stiffer-looking units read lower) and single-position tests of the same
    reducer are separate series: each chart holds one method only, and a method with too few runs says so."""
    rng = np.random.default_rng(11)
    with open_store(None, tmp_path / "data", bench_id="line-a", bench_name="bench line-a") as store:
        for i in range(30):
            positions = i % 3 == 0  # every third test at 4 positions
            request = {"reducer": "RV-110E", "serial_number": f"SN-{i}", **({"positions": 4} if positions else {})}
            profile = {"plan": "positions", "positions_deg": [0.0, 90.0, 180.0, 270.0]} if positions else None
            store.create_run(f"run-{i:02d}", request, ("time_s",), profile=profile)
            value = rng.normal(294.0, 0.5) - (6.0 if positions else 0.0)  # the worst of 4 sits lower
            store.set_status(f"run-{i:02d}", "completed", results={"rigidity_nm_per_arcmin": value})
        store.create_run("run-rates", {"reducer": "RV-110E", "rates": [50.0, 100.0, 200.0]}, ("time_s",))
        store.set_status("run-rates", "completed", results={"rigidity_nm_per_arcmin": 290.0})
    with serve(settings_factory(), runner=ScriptedRunner(bench_id="line-a")) as server:
        c = server.client()
        single = c.get("/api/spc/chart", params={"reducer": "RV-110E"}).json()
        four = c.get("/api/spc/chart", params={"reducer": "RV-110E", "method": "positions-4"}).json()
        assert single["methods"] == four["methods"] == {"positions-4": 10, "rates-3": 1, "single": 20}
        assert [r["id"] for r in single["runs"]] == [f"run-{i:02d}" for i in range(30) if i % 3]
        assert [r["id"] for r in four["runs"]] == [f"run-{i:02d}" for i in range(0, 30, 3)]
        assert single["chart"]["out_of_control"] == [] and four["chart"]["out_of_control"] == []
        assert abs(single["chart"]["center"] - four["chart"]["center"] - 6.0) < 1.0
        assert four["baseline_n"] == 10 and four["limits"] == "provisional"
        rates = c.get("/api/spc/chart", params={"reducer": "RV-110E", "method": "rates-3"}).json()
        assert rates["chart"] is None and rates["note"].startswith("too few runs: 1 completed rates-3 runs")
        assert "(other methods: positions-4 (10), single (20))" in rates["note"]

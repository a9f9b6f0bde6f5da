"""Many benches, one PostgreSQL: services list and serve each other's runs; a killed service's run is interrupted
with its committed samples; a bench's restart leaves another bench's running test alone; the list's filters.

The database is a throwaway PostgreSQL server started by the session (tests/conftest.py)."""

from __future__ import annotations

import contextlib
import io

import numpy as np
import pytest
from svc_helpers import (
    ScriptedRunner,
    kill_during_a_run,
    serve,
    start_serve_process,
    stop_process,
    wait_for,
)

from tcms_daq.samples import parse_csv_text

REQUEST = {"reducer": "RV-110E", "max_torque_nm": 200, "cycles": 1, "rate_nm_per_s": 400}


def _run_to_end(client, **extra) -> str:
    run_id = client.post("/api/tests", json={**REQUEST, **extra}).json()["id"]
    wait_for(lambda: client.get(f"/api/tests/{run_id}").json()["status"] == "completed", timeout_s=60)
    return run_id


def test_two_services_on_one_postgres_list_filter_and_serve_each_others_runs(settings_factory, postgres_url,
                                                                               tmp_path):
    line1 = ScriptedRunner(bench_name="Line 1 bench", bench_id="line-1", speed=50.0)
    line2 = ScriptedRunner(bench_name="Line 2 bench", bench_id="line-2", speed=50.0)
    s1 = settings_factory(store_url=postgres_url, data_dir=tmp_path / "one")
    s2 = settings_factory(store_url=postgres_url, data_dir=tmp_path / "two")
    with serve(s1, runner=line1) as one, serve(s2, runner=line2) as two:
        c1, c2 = one.client(), two.client()
        a = _run_to_end(c1, serial_number="REF-0042", operator="Ada")
        b = _run_to_end(c2, serial_number="REF-0042", operator="Bob")
        c = _run_to_end(c2, serial_number="SN-7")

        for client in (c1, c2):  # each lists every bench's runs, newest first, with its bench
            listed = client.get("/api/tests")
            assert listed.status_code == 200 and listed.headers["X-Total-Count"] == "3"
            assert listed.headers["X-Total-Count-Exact"] == "true"  # counted: far below the estimate's threshold
            assert [(r["id"], r["bench_id"]) for r in listed.json()] == [(c, "line-2"), (b, "line-2"), (a, "line-1")]
        by_serial = c1.get("/api/tests", params={"serial": "ref-0042"})
        assert {r["id"] for r in by_serial.json()} == {a, b} and by_serial.headers["X-Total-Count"] == "2"
        assert [r["request"]["serial_number"] for r in by_serial.json()] == ["REF-0042", "REF-0042"]
        assert [r["id"] for r in c1.get("/api/tests", params={"bench": "Line 2 bench"}).json()] == [c, b]
        assert [r["id"] for r in c2.get("/api/tests", params={"q": "ada"}).json()] == [a]
        assert [r["id"] for r in c2.get("/api/tests", params={"bench": "line-1", "status": "completed",
                                                              "verdict": "pass"}).json()] == [a]
        page = c1.get("/api/tests", params={"limit": 1, "offset": 1})
        assert [r["id"] for r in page.json()] == [b] and page.headers["X-Total-Count"] == "3"
        created = c1.get(f"/api/tests/{b}").json()["created_at"]
        assert {r["id"] for r in c1.get("/api/tests", params={"since": created}).json()} == {b, c}
        assert [r["id"] for r in c1.get("/api/tests", params={"until": created}).json()] == [b, a]

        # each serves the other's samples, byte for byte what the other recorded
        for own, other, run_id in ((c1, c2, b), (c2, c1, a)):
            mine = parse_csv_text(other.get(f"/api/tests/{run_id}/samples?format=csv").text)
            theirs = parse_csv_text(own.get(f"/api/tests/{run_id}/samples?format=csv").text)
            assert len(theirs["time_s"]) == own.get(f"/api/tests/{run_id}").json()["sample_count"] > 100
            for name in ("time_s", "torque_nm", "angle_arcsec"):
                np.testing.assert_array_equal(theirs[name], mine[name])
        loop = c1.get(f"/api/tests/{b}/loop", params={"max_points": 200}).json()
        assert 0 < len(loop["torque_nm"]) == len(loop["angle_arcsec"]) <= 200 and loop["samples"] > 200
        assert max(loop["torque_nm"]) == pytest.approx(200.0, abs=1.0)  # the loop's tip is kept

        for params, word in (({"status": "done"}, "status"), ({"verdict": "ok"}, "verdict"),
                             ({"since": "yesterday"}, "since"), ({"limit": 0}, "limit"), ({"offset": -1}, "offset"),
                             ({"since": "2030-01-02T00:00:00Z", "until": "2030-01-01T00:00:00Z"}, "after until")):
            r = c1.get("/api/tests", params=params)
            assert r.status_code == 422 and word in r.json()["detail"], (params, r.text)


@pytest.mark.timeout(180)
def test_killed_service_on_postgres_interrupts_its_run_and_keeps_its_committed_samples(sim_config, postgres_url,
                                                                                      tmp_path):
    import httpx

    from tcms_daq.store.postgres_store import PostgresRunStore

    args = ["--port", "0", "--data-dir", str(tmp_path / "data"), "--config", str(sim_config), "--sim-speed", "5",
            "--store", postgres_url]
    proc, base = start_serve_process(args)
    run_id = kill_during_a_run(proc, base, {"reducer": "RV-110E", "max_torque_nm": 500, "cycles": 3,
                                            "rate_nm_per_s": 50, "serial_number": "SN-KILL"}, timeout_s=90)

    # meanwhile another bench runs a test in the same database: the restart must leave it running
    other = PostgresRunStore(postgres_url, bench_id="line-9", bench_name="another bench")
    other.create_run("other-running", {"reducer": "RV-110E"}, ("time_s", "torque_nm", "angle_arcsec"))
    other.set_status("other-running", "running")
    with PostgresRunStore(postgres_url, recover=False) as reader:
        committed = reader.get_run(run_id).sample_count
        assert committed > 500 and reader.get_run(run_id).status == "running"

    proc2, base2 = start_serve_process(args)
    try:
        c2 = httpx.Client(base_url=base2, timeout=20)
        run = c2.get(f"/api/tests/{run_id}").json()
        assert run["status"] == "interrupted" and "stopped" in run["error"]
        assert run["sample_count"] == committed and run["bench_id"] == "sim-1"
        csv = parse_csv_text(c2.get(f"/api/tests/{run_id}/samples?format=csv").text)
        assert len(csv["time_s"]) == committed and np.all(np.diff(csv["time_s"]) > 0)
        assert c2.get("/api/tests/other-running").json()["status"] == "running"
        assert [r["id"] for r in c2.get("/api/tests", params={"serial": "SN-KILL"}).json()] == [run_id]
    finally:
        stop_process(proc2)
        other.close()


def test_second_service_of_one_bench_on_postgres_is_a_one_line_error(sim_config, postgres_url, tmp_path):
    from tcms_daq.cli import main
    from tcms_daq.store.postgres_store import PostgresRunStore

    with PostgresRunStore(postgres_url, bench_id="sim-1"):
        err = io.StringIO()
        with contextlib.redirect_stderr(err):
            code = main(["serve", "--config", str(sim_config), "--port", "0", "--data-dir", str(tmp_path),
                         "--store", postgres_url])
    assert code == 2
    line = err.getvalue().strip()
    assert "already served by another service" in line and "\n" not in line
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        assert main(["serve", "--config", str(sim_config), "--port", "0", "--store", "mongodb://x/y"]) == 2
    assert "unknown scheme" in err.getvalue()

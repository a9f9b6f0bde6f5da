"""Both run store backends (SQLite, PostgreSQL) behave alike: runs, samples, bench scoping, queries, migrations.

The PostgreSQL cases run against a throwaway server the session starts (tests/conftest.py)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from tcms_daq.store import RunQuery, RunStore, Store, StoreError, open_store
from tcms_daq.store.base import INTERRUPTED_ERROR, RunTotal

CHANNELS = ("time_s", "torque_nm", "angle_arcsec", "encoder_arcsec")
Opener = Callable[..., Store]


def _batch(start: int, n: int) -> dict[str, np.ndarray]:
    t = (start + np.arange(n)) * 1e-3
    return {"time_s": t, "torque_nm": np.sin(t), "angle_arcsec": 2 * t, "encoder_arcsec": 2 * t + 0.5}


@pytest.fixture(params=["sqlite", "postgresql"])
def opener(request, tmp_path: Path) -> Opener:
    """open(bench_id=…, recover=…) → a store of the backend under test; every store opened is closed after."""
    url = request.getfixturevalue("postgres_url") if request.param == "postgresql" else None
    opened: list[Store] = []

    def open_(bench_id: str | None = "bench-a", recover: bool = True, bench_name: str | None = None) -> Store:
        store = open_store(url, tmp_path, bench_id=bench_id, bench_name=bench_name or f"Bench {bench_id}",
                           recover=recover)
        opened.append(store)
        return store

    yield open_
    for store in opened:
        store.close()


def test_runs_and_samples_round_trip(opener: Opener):
    store = opener()
    store.create_run("r1", {"reducer": "RV-110E", "serial_number": "SN-1"}, CHANNELS,
                     profile={"kind": "continuous"}, config_snapshot={"bench": {"name": "x"}},
                     compensator_toml="[x]\n", compensation_version=None)
    assert store.append_samples("r1", [_batch(0, 100), _batch(100, 50)]) == 150
    store.append_samples("r1", [_batch(150, 7)])
    store.set_status("r1", "running")
    results = {"rigidity_nm_per_arcmin": 290.5, "verdict": {"passed": False, "decision": "undecided"}}
    store.set_status("r1", "completed", results=results)
    rec = store.get_run("r1")
    assert rec.status == "completed" and rec.sample_count == 157 and rec.results == results
    assert rec.verdict == "undecided" and rec.bench_id == "bench-a" and rec.bench_name == "Bench bench-a"
    assert rec.config_snapshot == {"bench": {"name": "x"}} and rec.compensator_toml == "[x]\n"
    assert rec.started_at is not None and rec.finished_at >= rec.started_at
    cols = store.read_columns("r1")
    np.testing.assert_array_equal(cols["time_s"], np.arange(157) * 1e-3)
    np.testing.assert_array_equal(cols["encoder_arcsec"], 2 * cols["time_s"] + 0.5)
    chunks = list(store.iter_columns("r1", chunk_samples=100))
    assert [len(c["time_s"]) for c in chunks] == [100, 50, 7]
    assert len(store.read_samples("r1")) == 157


def test_bad_input_is_rejected_without_losing_data(opener: Opener):
    store = opener()
    store.create_run("r1", {}, CHANNELS)
    store.append_samples("r1", [_batch(0, 10)])
    with pytest.raises(StoreError, match="lacks channel 'encoder_arcsec'"):
        store.append_samples("r1", [{"time_s": np.zeros(3), "torque_nm": np.zeros(3), "angle_arcsec": np.zeros(3)}])
    with pytest.raises(StoreError, match="differ in length"):
        store.append_samples("r1", [{**_batch(0, 3), "time_s": np.zeros(4)}])
    with pytest.raises(StoreError, match="already exists"):
        store.create_run("r1", {}, CHANNELS)
    with pytest.raises(StoreError, match="unknown run"):
        store.set_status("nope", "completed")
    with pytest.raises(StoreError, match="unknown run"):
        store.append_samples("nope", [_batch(0, 3)])
    with pytest.raises(StoreError, match="unknown run status"):
        store.set_status("r1", "finished")
    assert store.get_run("r1").sample_count == 10
    assert len(store.read_columns("r1")["time_s"]) == 10


def test_restart_interrupts_only_its_own_benchs_runs(opener: Opener):
    a = opener("bench-a")
    b = opener("bench-b")
    a.create_run("a-live", {}, CHANNELS)
    a.set_status("a-live", "running")
    a.append_samples("a-live", [_batch(0, 30)])
    a.create_run("a-done", {}, CHANNELS)
    a.set_status("a-done", "completed", results={"x": 1.0})
    b.create_run("b-live", {}, CHANNELS)
    b.set_status("b-live", "running")
    a.close()  # bench a's service goes away (its process died)
    reader = opener(None, recover=False)  # a reader never marks anything
    assert reader.recovered_run_ids == [] and reader.get_run("a-live").status == "running"
    a2 = opener("bench-a")  # bench a restarts
    assert a2.recovered_run_ids == ["a-live"]
    live = a2.get_run("a-live")
    assert live.status == "interrupted" and live.error == INTERRUPTED_ERROR and live.sample_count == 30
    assert len(a2.read_columns("a-live")["torque_nm"]) == 30
    assert a2.get_run("b-live").status == "running"  # bench b's test goes on
    assert a2.get_run("a-done").status == "completed"
    assert a2.count_by_status()["interrupted"] == 1
    assert a2.count_by_status()["running"] == 0 and b.count_by_status()["running"] == 1  # each its own bench


def test_versioned_documents_belong_to_their_bench(opener: Opener):
    a = opener("bench-a")
    b = opener("bench-b")
    va = a.add_compensation("[compensator]\n# a\n", note="a's")
    vb = b.add_compensation("[compensator]\n# b\n", note="b's")
    assert a.compensation()[1].endswith("# a\n") and b.compensation()[1].endswith("# b\n")
    assert a.compensation(vb.version) is None and b.compensation(va.version) is None
    assert [v.note for v in a.compensation_history()] == ["a's"]
    ma = a.add_bench_model("[model]\n", note="m", analysis_id="an-1", run_id="r-1")
    assert b.bench_model() is None and a.bench_model()[0] == ma
    assert a.bench_model_history()[0].analysis_id == "an-1"


def test_queries_filter_and_paginate(opener: Opener):
    a = opener("bench-a", bench_name="Line 1 bench")
    b = opener("bench-b", bench_name="Line 2 bench")
    for i in range(5):
        store = a if i % 2 == 0 else b
        run_id = f"r{i}"
        store.create_run(run_id, {"reducer": "RV-110E" if i < 3 else "RV-60N", "serial_number": f"SN-{i % 2}",
                                  "operator": "Ada" if i == 4 else "Bob"}, CHANNELS)
        store.set_status(run_id, "completed", results={"verdict": {"passed": i != 1}})
    total = a.count_runs()
    assert total == 5 and [r.id for r in a.list_runs()] == ["r4", "r3", "r2", "r1", "r0"]
    assert [r.id for r in a.list_runs(2, 1)] == ["r3", "r2"]
    assert {r.id for r in b.list_runs(query=RunQuery(bench="bench-a"))} == {"r0", "r2", "r4"}
    assert {r.id for r in b.list_runs(query=RunQuery(bench="line 2 BENCH"))} == {"r1", "r3"}
    assert {r.id for r in a.list_runs(query=RunQuery(serial="sn-1"))} == {"r1", "r3"}
    assert {r.id for r in a.list_runs(query=RunQuery(reducer="RV-60N"))} == {"r3", "r4"}
    assert {r.id for r in a.list_runs(query=RunQuery(verdict="fail"))} == {"r1"}
    assert a.count_runs(RunQuery(verdict="pass", serial="SN-0")) == 3
    assert {r.id for r in a.list_runs(query=RunQuery(text="ada"))} == {"r4"}
    assert a.list_runs(query=RunQuery(text="100%_")) == []  # LIKE wildcards are literal
    assert a.count_runs(RunQuery(status="running")) == 0
    newest = a.get_run("r4").created_at
    assert {r.id for r in a.list_runs(query=RunQuery(since=newest))} == {"r4"}
    assert a.count_runs(RunQuery(until=newest - 1e3)) == 0
    for bad in ({"status": "done"}, {"verdict": "maybe"}, {"since": 2.0, "until": 1.0}, {"since": float("nan")}):
        with pytest.raises(StoreError):
            RunQuery(**bad)


def test_the_lists_total_is_exact_up_to_its_limit_and_an_estimate_past_it(opener: Opener):
    store = opener()
    for i in range(6):
        store.create_run(f"r{i}", {"reducer": "RV-110E", "serial_number": f"SN-{i % 3}"}, CHANNELS)
    assert store.total_runs() == RunTotal(6, exact=True)
    assert store.total_runs(RunQuery(serial="SN-1"), exact_up_to=2) == RunTotal(2, exact=True)  # at the limit
    past = store.total_runs(exact_up_to=3)
    if isinstance(store, RunStore):  # one bench's file: always counted
        assert past == RunTotal(6, exact=True)
    else:  # PostgreSQL: the planner's estimate, never below the limit + 1 it counted
        assert not past.exact and past.count >= 4


def test_postgres_second_service_of_a_bench_is_refused_and_migrations_are_idempotent(postgres_url):
    from tcms_daq.store.postgres_store import MIGRATIONS, PostgresRunStore

    first = PostgresRunStore(postgres_url, bench_id="bench-a")
    try:
        assert first.schema_version == len(MIGRATIONS)
        with pytest.raises(StoreError, match="already served by another service"):
            PostgresRunStore(postgres_url, bench_id="bench-a")
        other = PostgresRunStore(postgres_url, bench_id="bench-b")  # another bench: welcome
        reader = PostgresRunStore(postgres_url, recover=False, bench_id="bench-a")  # a reader: welcome
        assert other.schema_version == reader.schema_version == len(MIGRATIONS)
        other.close()
        reader.close()
    finally:
        first.close()
    again = PostgresRunStore(postgres_url, bench_id="bench-a")  # the lock went with the first store
    again.close()


def test_postgres_unreachable_is_one_line(tmp_path):
    with pytest.raises(StoreError, match=r"cannot connect") as info:
        open_store("postgresql://nobody:secret@127.0.0.1:1/none", tmp_path, bench_id="x")
    assert "secret" not in str(info.value) and "\n" not in str(info.value)
    with pytest.raises(StoreError, match="unknown scheme"):
        open_store("mysql://x/y", tmp_path)


def test_headline_points_are_the_same_on_both_backends(opener: Opener):
    """SPC's series: of the newest runs matching a query, those with a finite value, oldest first (PostgreSQL
    reads the headline columns it keeps beside the results, SQLite the results)."""
    store = opener()
    for i, value in enumerate([290.0, None, 291.5, 289.0]):
        store.create_run(f"h{i}", {"reducer": "RV-110E" if i != 3 else "RV-40E", "serial_number": f"SN-{i}",
                                   **({"positions": 4} if i == 2 else {})}, CHANNELS)
        results = {"lost_motion_arcsec": 25.0} if value is None else {"rigidity_nm_per_arcmin": value}
        store.set_status(f"h{i}", "completed", results=results)
    points = store.headline_points("rigidity_nm_per_arcmin", RunQuery(reducer="rv-110e", status="completed"), 100)
    assert [(p.id, p.value, p.series, p.serial_number) for p in points] == [("h0", 290.0, "single", "SN-0"),
                                                                            ("h2", 291.5, "positions-4", "SN-2")]
    newest_two = store.headline_points("rigidity_nm_per_arcmin", RunQuery(reducer="RV-110E"), 2)
    assert [p.id for p in newest_two] == ["h2"]  # h1, the other of the newest two, has no rigidity


def test_a_brief_list_carries_the_headline_results_their_uncertainty_and_the_verdict(opener: Opener):
    from tcms_daq.store.base import brief_results

    store = opener()
    results = {"rigidity_nm_per_arcmin": 290.5, "lost_motion_arcsec": None, "stages": [{"big": list(range(50))}],
               "uncertainty": {"rigidity_nm_per_arcmin": {"U": 2.0, "k": 2.0, "u": 1.0, "note": None},
                               "hysteresis_area": {"U": 1.0}},
               "verdict": {"passed": True, "decision": "pass", "reasons": None}}
    store.create_run("b1", {"reducer": "RV-110E"}, CHANNELS)
    store.set_status("b1", "completed", results=results)
    store.create_run("b2", {"reducer": "RV-110E"}, CHANNELS)
    store.set_status("b2", "completed", results={"backlash_arcsec": 20.0, "uncertainty": []})
    store.create_run("b3", {"reducer": "RV-110E"}, CHANNELS)
    brief = {r.id: r.results for r in store.list_runs(10, brief=True)}
    assert brief == {"b1": brief_results(results), "b2": {"backlash_arcsec": 20.0}, "b3": None}
    assert brief["b1"] == {"rigidity_nm_per_arcmin": 290.5, "lost_motion_arcsec": None,
                           "uncertainty": {"rigidity_nm_per_arcmin": {"U": 2.0, "k": 2.0, "u": 1.0, "note": None}},
                           "verdict": {"passed": True, "decision": "pass", "reasons": None}}
    assert {r.id: r.results for r in store.list_runs(10)}["b1"] == results
    if not isinstance(store, RunStore):  # PostgreSQL: the runs written before migration 5 are reduced when listed
        with store._connection() as conn:  # type: ignore[attr-defined]
            stored = dict(conn.execute("SELECT id, results_brief FROM runs").fetchall())
            assert stored == brief
            conn.execute("UPDATE runs SET results_brief = NULL")
        assert {r.id: r.results for r in store.list_runs(10, brief=True)} == brief


def test_postgres_fleet_queries_use_their_indexes(postgres_url):
    """On 20 000 runs (a month of a plant): the text search uses the trigram index (its expressions match the
    query's), SPC and the list's filters are answered from their indexes alone (index-only scans, never the runs'
    wide rows)."""
    import psycopg

    from tcms_daq.store.postgres_store import PostgresRunStore

    PostgresRunStore(postgres_url, recover=False).close()  # the schema
    with psycopg.connect(postgres_url, autocommit=True) as conn:
        conn.execute(
            "INSERT INTO runs (id, created_at, status, request, channels, bench_id, bench_name, reducer, serial_number, "
            "operator, verdict, rigidity_nm_per_arcmin, test_series) "
            "SELECT 'r' || i, 1.8e9 + i * 60, 'completed', '{}', '[]', 'bench-' || (i % 20), 'Bench ' || (i % 20), "
            "'RV-' || (i % 7), 'SN-' || lpad(i::text, 6, '0'), 'op-' || (i % 30), "
            "CASE WHEN i % 29 = 0 THEN 'fail' ELSE 'pass' END, 300 + i % 10, 'single' "
            "FROM generate_series(1, 20000) AS i")
        conn.execute("VACUUM ANALYZE runs")

        def plan(query: RunQuery, sql: str) -> str:
            where, params = query.where("%s", "ILIKE")
            return "\n".join(r[0] for r in conn.execute("EXPLAIN " + sql.format(where=where), params))

        text = plan(RunQuery(text="SN-01234"), "SELECT id FROM runs {where} ORDER BY created_at DESC, id DESC LIMIT 100")
        assert "runs_text" in text, text
        spc = plan(RunQuery(reducer="RV-3", status="completed"),
                   "SELECT id, created_at, bench_id, serial_number, test_series, rigidity_nm_per_arcmin FROM runs "
                   "{where} ORDER BY created_at DESC, id DESC LIMIT 10000")
        assert "Index Only Scan using runs_reducer" in spc, spc
        for query in (RunQuery(), RunQuery(since=1.8e9 + 6e5), RunQuery(status="completed", verdict="pass")):
            listed = plan(query, "SELECT id FROM runs {where} ORDER BY created_at DESC, id DESC LIMIT 100 OFFSET 1000")
            assert "Index Only Scan using runs_created" in listed, listed

"""A plant's years of samples on PostgreSQL: samples partitioned by month of the run's creation (one partition read
per run), the migration that moves version-1 samples into them, and the retention policy that drops whole months
(records and results stay; the samples are retired: SamplesRetired, 410 in the API).

Against the throwaway PostgreSQL server of the test session (tests/conftest.py)."""

from __future__ import annotations

import calendar
from types import SimpleNamespace

import numpy as np
import psycopg
import pytest

from tcms_daq.cli import main
from tcms_daq.cli.store import cutoff_s
from tcms_daq.store import RunQuery
from tcms_daq.store.base import SamplesRetired
from tcms_daq.store.postgres_store import MIGRATIONS, PostgresRunStore

CHANNELS = ("time_s", "torque_nm")


def _utc(year: int, month: int, day: int = 15) -> float:
    return float(calendar.timegm((year, month, day, 12, 0, 0)))


def _batch(start: int, n: int) -> dict[str, np.ndarray]:
    t = (start + np.arange(n)) * 1e-3
    return {"time_s": t, "torque_nm": np.sin(t)}


def _run_at(store: PostgresRunStore, monkeypatch, run_id: str, when_s: float, status: str = "completed") -> None:
    with monkeypatch.context() as m:  # the store's clock only: the run is created in that month
        m.setattr("tcms_daq.store.postgres_store.time", SimpleNamespace(time=lambda: when_s))
        store.create_run(run_id, {"reducer": "RV-110E"}, CHANNELS)
    store.append_samples(run_id, [_batch(0, 100), _batch(100, 20)])
    if status != "queued":
        store.set_status(run_id, status, results={"rigidity_nm_per_arcmin": 290.0} if status == "completed" else None)


def test_samples_live_in_the_month_of_their_run_and_a_run_reads_one_partition(postgres_url, monkeypatch):
    with PostgresRunStore(postgres_url, bench_id="b1") as store:
        _run_at(store, monkeypatch, "jan", _utc(2025, 1, 31))
        _run_at(store, monkeypatch, "feb", _utc(2025, 2, 1))
        _run_at(store, monkeypatch, "feb2", _utc(2025, 2, 20))
        parts = store.sample_partitions()
        assert [(p.name, p.runs) for p in parts] == [("sample_batches_y2025m01", 1), ("sample_batches_y2025m02", 2)]
        assert parts[0].from_s == calendar.timegm((2025, 1, 1, 0, 0, 0)) == parts[0].to_s - 31 * 86400
        np.testing.assert_array_equal(store.read_columns("feb")["time_s"], np.arange(120) * 1e-3)
        with psycopg.connect(postgres_url) as conn:
            in_feb = conn.execute("SELECT count(*) FROM sample_batches_y2025m02").fetchone()[0]
            plan = "\n".join(r[0] for r in conn.execute(
                "EXPLAIN (ANALYZE, COSTS OFF) SELECT batch_index FROM sample_batches WHERE run_id = 'feb' AND "
                "run_created_at = (SELECT created_at FROM runs WHERE id = 'feb') AND batch_index >= 0"))
        assert in_feb == 4
        assert "sample_batches_y2025m01" not in plan or "never executed" in plan, plan


def test_retention_drops_whole_old_months_keeps_records_and_a_month_with_an_active_run(postgres_url, monkeypatch):
    with PostgresRunStore(postgres_url, bench_id="b1") as store:
        _run_at(store, monkeypatch, "old", _utc(2024, 3))
        _run_at(store, monkeypatch, "running-old", _utc(2024, 4), status="running")
        _run_at(store, monkeypatch, "recent", _utc(2025, 6))
        cutoff = cutoff_s(None, "2025-01")
        planned = store.retire_samples(cutoff, dry_run=True)
        assert [p.name for p in planned] == ["sample_batches_y2024m03"]
        assert len(store.sample_partitions()) == 3, "a dry run drops nothing"
        dropped = store.retire_samples(cutoff)
        assert [p.name for p in dropped] == ["sample_batches_y2024m03"]
        assert [p.name for p in store.sample_partitions()] == ["sample_batches_y2024m04", "sample_batches_y2025m06"]
        old = store.get_run("old")
        assert old is not None and old.results == {"rigidity_nm_per_arcmin": 290.0} and old.sample_count == 120
        assert old.samples_retired_at is not None
        with pytest.raises(SamplesRetired, match="samples of run old were retired on .* retention policy"):
            store.read_columns("old")
        with pytest.raises(SamplesRetired):
            old.require_samples()
        assert len(store.read_columns("recent")["time_s"]) == 120 and len(store.read_columns("running-old")["time_s"])
        assert store.get_run("recent").samples_retired_at is None
        # a new run in a retired month gets its month again
        _run_at(store, monkeypatch, "late-import", _utc(2024, 3, 2))
        assert len(store.read_columns("late-import")["time_s"]) == 120


def test_migration_moves_version_1_samples_into_month_partitions(postgres_url):
    created = _utc(2025, 5)
    blob = np.stack([np.arange(3.0), np.ones(3)]).astype("<f8").tobytes()
    with psycopg.connect(postgres_url, autocommit=True) as conn:
        conn.execute("CREATE TABLE schema_version (version integer NOT NULL)")
        conn.execute(MIGRATIONS[0])
        conn.execute("INSERT INTO schema_version VALUES (1)")
        conn.execute("INSERT INTO runs (id, created_at, status, request, channels, sample_count, results) VALUES "
                     "('v1', %s, 'completed', '{\"positions\": 4}', '[\"time_s\", \"torque_nm\"]', 6, "
                     "'{\"rigidity_nm_per_arcmin\": 291.5, \"backlash_arcsec\": \"n/a\"}')", (created,))
        conn.execute("INSERT INTO sample_batches VALUES ('v1', 0, 3, %s), ('v1', 1, 3, %s)", (blob, blob))
    with PostgresRunStore(postgres_url, recover=False) as store:
        assert store.schema_version == len(MIGRATIONS)
        assert [p.name for p in store.sample_partitions()] == ["sample_batches_y2025m05"]
        np.testing.assert_array_equal(store.read_columns("v1")["time_s"], [0, 1, 2, 0, 1, 2])
        points = store.headline_points("rigidity_nm_per_arcmin", RunQuery(), 10)
        assert [(p.id, p.series, p.value) for p in points] == [("v1", "positions-4", 291.5)]
        assert store.headline_points("backlash_arcsec", RunQuery(), 10) == []  # not a number: not a point


def test_cli_lists_months_and_retires_them(postgres_url, monkeypatch, capsys):
    with PostgresRunStore(postgres_url, bench_id="b1") as store:
        _run_at(store, monkeypatch, "old", _utc(2023, 12))
    assert main(["store", "partitions", "--store", postgres_url]) == 0
    out = capsys.readouterr().out
    assert "sample_batches_y2023m12  2023-12          1 runs" in out and "1 month(s) of samples" in out
    assert main(["store", "retire", "--store", postgres_url, "--keep-months", "12", "--dry-run"]) == 0
    assert "would drop 1 month(s)" in capsys.readouterr().out
    assert main(["store", "retire", "--store", postgres_url, "--before", "2024-01"]) == 0
    assert "dropped 1 month(s) of samples (1 runs' samples" in capsys.readouterr().out
    assert main(["store", "retire", "--store", postgres_url, "--keep-months", "0"]) == 2
    assert "--keep-months must be at least 1" in capsys.readouterr().err
    monkeypatch.delenv("TCMS_STORE_URL", raising=False)
    assert main(["store", "partitions"]) == 2
    assert "retention is the PostgreSQL store's" in capsys.readouterr().err


def test_cutoff_keeps_this_month_and_the_ones_before():
    now = _utc(2026, 3, 10)
    assert cutoff_s(1, None, now) == calendar.timegm((2026, 3, 1, 0, 0, 0))
    assert cutoff_s(3, None, now) == calendar.timegm((2026, 1, 1, 0, 0, 0))
    assert cutoff_s(15, None, now) == calendar.timegm((2025, 1, 1, 0, 0, 0))

"""A run whose samples the PostgreSQL store's retention policy retired: its record and results are still served,
every answer that needs its samples is a 410 Gone naming the retirement (never a 500 or an empty file)."""

from __future__ import annotations

import time

from svc_helpers import ScriptedRunner, serve, wait_for

from tcms_daq.store.postgres_store import PostgresRunStore

REQUEST = {"reducer": "RV-110E", "max_torque_nm": 200, "cycles": 1, "rate_nm_per_s": 400}


def test_retired_samples_answer_410_and_the_results_remain(settings_factory, postgres_url, tmp_path):
    runner = ScriptedRunner(bench_name="Line 1 bench", bench_id="line-1", speed=50.0)
    with serve(settings_factory(store_url=postgres_url), runner=runner) as server:
        client = server.client()
        run_id = client.post("/api/tests", json=REQUEST).json()["id"]
        wait_for(lambda: client.get(f"/api/tests/{run_id}").json()["status"] == "completed", timeout_s=60)
        assert client.get(f"/api/tests/{run_id}/samples").status_code == 200
        with PostgresRunStore(postgres_url, recover=False) as admin:
            # a cutoff beyond this month: every month without an active run goes
            assert admin.retire_samples(time.time() + 62 * 86400)
        kept = client.get(f"/api/tests/{run_id}")
        assert kept.status_code == 200 and kept.json()["status"] == "completed" and kept.json()["results"]
        for path in ("samples", "samples?format=parquet", "metadata", "certificate.pdf", "report", "loop"):
            answer = client.get(f"/api/tests/{run_id}/{path}")
            assert answer.status_code == 410, (path, answer.status_code, answer.text[:200])
            assert "retired" in answer.json()["detail"] and "retention policy" in answer.json()["detail"]
        assert client.get("/api/tests/no-such-run/samples").status_code == 404

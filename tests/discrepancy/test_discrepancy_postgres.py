"""The discrepancy archive and the versioned bench model on PostgreSQL: what an analysis of one bench's run names
becomes that bench's next bench model version (not another bench's), and its next run compares against it."""

from __future__ import annotations

from tcms_daq.sim.physics import catalogue_model
from tcms_daq.sim.trials import bench_run

from tcms_daq.store import open_store
from tcms_daq.store.discrepancy import AnalysisArchive, bench_model

DRIFT = {"thermal_drift": {"rate_arcsec_per_s": 0.03}}
CHANNELS = ("time_s", "torque_nm", "angle_arcsec")


def _store_run(store, run_id: str, samples) -> None:
    store.create_run(run_id, {"reducer": "RV-110E"}, CHANNELS, status="completed")
    store.append_samples(run_id, [{"time_s": samples.time_s, "torque_nm": samples.torque_nm,
                                   "angle_arcsec": samples.angle_arcsec}])


def test_analyse_and_apply_on_postgres_stay_with_their_bench(postgres_url, tmp_path):
    a = open_store(postgres_url, tmp_path, bench_id="line-a", bench_name="A")
    b = open_store(postgres_url, tmp_path, bench_id="line-b", bench_name="B")
    try:
        _store_run(a, "run-1", bench_run(DRIFT, 41)[0])
        _store_run(a, "run-2", bench_run(DRIFT, 42)[0])
        archive = AnalysisArchive(tmp_path / "discrepancy")
        first = archive.analyse(a, "run-1", catalogue_model)
        assert [e["name"] for e in first["effects"]] == ["thermal_drift"] and first["model_version"] == 0
        applied = archive.apply(a, first["id"])
        assert bench_model(a)[0] == applied.version and a.bench_model_history()[0].run_id == "run-1"
        assert bench_model(b)[0] == 0  # bench b's model is untouched
        second = archive.analyse(a, "run-2", catalogue_model)
        assert second["model_version"] == applied.version and second["verdict"] == "consistent"
        # bench b may analyse bench a's run (the store is shared) against its own model
        assert archive.analyse(b, "run-2", catalogue_model)["model_version"] == 0
    finally:
        a.close()
        b.close()

import numpy as np
import pytest

from tcms_daq.store import Recorder, RunStore, StoreError

CHANNELS = ("time_s", "torque_nm", "angle_arcsec", "encoder_arcsec")


def _batch(start: int, n: int) -> dict[str, np.ndarray]:
    t = (start + np.arange(n)) * 1e-3
    return {"time_s": t, "torque_nm": np.sin(t), "angle_arcsec": 2 * t, "encoder_arcsec": 2 * t + 0.5}


def test_runs_and_samples_round_trip(tmp_path):
    with RunStore(tmp_path / "s.db") as store:
        store.create_run("r1", {"reducer": "RV-110E"}, CHANNELS, profile={"kind": "continuous"},
                         config_snapshot={"bench": {"name": "x"}}, compensator_toml="[x]\n")
        assert store.append_samples("r1", [_batch(0, 100), _batch(100, 50)]) == 150
        store.append_samples("r1", [_batch(150, 7)])
        store.set_status("r1", "running")
        store.set_status("r1", "completed", results={"rigidity_nm_per_arcmin": 290.5})
        rec = store.get_run("r1")
        assert rec.status == "completed" and rec.sample_count == 157
        assert rec.results == {"rigidity_nm_per_arcmin": 290.5}
        assert rec.config_snapshot == {"bench": {"name": "x"}} and rec.compensator_toml == "[x]\n"
        assert rec.started_at is not None and rec.finished_at >= rec.started_at
        cols = store.read_columns("r1")
        np.testing.assert_array_equal(cols["time_s"], (np.arange(157)) * 1e-3)
        np.testing.assert_array_equal(cols["encoder_arcsec"], 2 * cols["time_s"] + 0.5)
        samples = store.read_samples("r1")
        assert len(samples) == 157 and "encoder_arcsec" in samples.extra


def test_bad_input_is_rejected_without_losing_data(tmp_path):
    with RunStore(tmp_path / "s.db") as store:
        store.create_run("r1", {}, CHANNELS)
        store.append_samples("r1", [_batch(0, 10)])
        with pytest.raises(StoreError, match="lacks channel 'encoder_arcsec'"):
            store.append_samples("r1", [{"time_s": np.zeros(3), "torque_nm": np.zeros(3), "angle_arcsec": np.zeros(3)}])
        with pytest.raises(StoreError, match="already exists"):
            store.create_run("r1", {}, CHANNELS)
        with pytest.raises(StoreError, match="unknown run"):
            store.set_status("nope", "completed")
        with pytest.raises(StoreError, match="unknown run status"):
            store.set_status("r1", "finished")
        assert store.get_run("r1").sample_count == 10
        assert len(store.read_columns("r1")["time_s"]) == 10


def test_reopen_marks_active_runs_interrupted_and_keeps_samples(tmp_path):
    path = tmp_path / "s.db"
    store = RunStore(path)
    store.create_run("done", {}, CHANNELS)
    store.set_status("done", "completed", results={"a": 1.0})
    store.create_run("live", {}, CHANNELS)
    store.set_status("live", "running")
    store.append_samples("live", [_batch(0, 30)])
    store.create_run("waiting", {}, CHANNELS)
    # no close(): as if the process died
    reader = RunStore(path, recover=False)  # a reader beside a live service leaves active runs alone
    assert reader.recovered_run_ids == [] and reader.get_run("live").status == "running"
    assert len(reader.read_columns("live")["time_s"]) == 30
    reader.close()
    reopened = RunStore(path)
    assert sorted(reopened.recovered_run_ids) == ["live", "waiting"]
    assert reopened.get_run("done").status == "completed"
    live = reopened.get_run("live")
    assert live.status == "interrupted" and "stopped" in live.error and live.sample_count == 30
    assert len(reopened.read_columns("live")["torque_nm"]) == 30
    assert reopened.count_by_status()["interrupted"] == 2
    assert [r.id for r in reopened.list_runs()][0] in {"done", "live", "waiting"}
    reopened.close()
    store.close()


def test_recorder_commits_in_background(tmp_path):
    with RunStore(tmp_path / "s.db") as store:
        store.create_run("r", {}, CHANNELS)
        rec = Recorder(store, "r", flush_interval_s=0.01)
        for i in range(20):
            rec.write(_batch(i * 10, 10))
        assert rec.close() == 200
        np.testing.assert_array_equal(store.read_columns("r")["time_s"], np.arange(200) * 1e-3)

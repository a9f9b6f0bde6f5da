"""``tcms discrepancy --run ID --apply``: what an analysis of a stored run names becomes the bench model's next
version, and the next run is compared against it (the same archive and store as the service's API)."""

from __future__ import annotations

import json

import pytest
from tcms_daq.sim.trials import bench_run
from tcms_daq.sim.unmodelled import UNMODELLED

from tcms_daq.cli import main
from tcms_daq.store import STORE_FILENAME, RunStore

DRIFT = {"thermal_drift": {"rate_arcsec_per_s": 0.03}}


def store_run(data_dir, run_id: str, samples) -> None:
    with RunStore(data_dir / STORE_FILENAME) as store:
        store.create_run(run_id, {"reducer": "RV-110E"}, ("time_s", "torque_nm", "angle_arcsec"), status="completed")
        store.append_samples(run_id, [{"time_s": samples.time_s, "torque_nm": samples.torque_nm,
                                       "angle_arcsec": samples.angle_arcsec}])


def analyse(data_dir, run_id, capsys, *extra) -> tuple[int, dict | str]:
    code = main(["discrepancy", "--run", run_id, "--data-dir", str(data_dir), "--json", *extra])
    captured = capsys.readouterr()
    return code, (json.loads(captured.out) if code == 0 else captured.err)


def test_apply_from_the_cli_then_the_next_run_is_consistent(tmp_path, capsys):
    store_run(tmp_path, "run-1", bench_run(DRIFT, 41)[0])
    store_run(tmp_path, "run-2", bench_run(DRIFT, 42)[0])
    code, first = analyse(tmp_path, "run-1", capsys, "--apply")
    assert code == 0, first
    assert [e["name"] for e in first["effects"]] == ["thermal_drift"] and first["verdict"] == "explained"
    assert first["model_version"] == 0 and first["applied_version"] == 1
    assert (tmp_path / "discrepancy" / first["id"] / "report.html").is_file()
    code, second = analyse(tmp_path, "run-2", capsys)
    assert code == 0 and second["model_version"] == 1
    assert second["verdict"] == "consistent" and second["effects"] == [], second["verdict_words"]
    with RunStore(tmp_path / STORE_FILENAME) as store:
        (latest, toml), = [store.bench_model()]
        assert latest.version == 1 and latest.analysis_id == first["id"] and latest.run_id == "run-1"
        assert 'name = "thermal_drift"' in toml


def test_provisional_names_need_an_explicit_yes(tmp_path, capsys):
    """A slip of the encoder is outside the catalogue: whatever is named is provisional and not applied unless
    the user accepts it."""
    measured = bench_run({}, 43)[0]
    slipped = UNMODELLED["encoder_slip"].transform(measured, None)
    store_run(tmp_path, "run-slip", slipped)
    code, err = analyse(tmp_path, "run-slip", capsys, "--apply")
    if code == 2 and "named no effect" in err:
        pytest.skip("nothing named on this seed: nothing to accept")
    assert code == 2 and "provisional" in err and "\n" not in err.strip()
    code, doc = analyse(tmp_path, "run-slip", capsys, "--apply", "--accept-provisional")
    assert code == 0 and doc["verdict"] in ("partially_explained", "unexplained") and doc["applied_version"] == 1


def test_apply_needs_a_stored_run(tmp_path, capsys):
    assert main(["discrepancy", "a.csv", "b.csv", "--apply"]) == 2
    assert "--apply adds the effects a stored run's analysis names" in capsys.readouterr().err

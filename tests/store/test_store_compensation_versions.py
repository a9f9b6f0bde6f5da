"""Compensation versions as a service object (``tcms_daq.store.compensation``) and its command line
(``tcms compensation list|show|upload|rollback|from-model``) on a SQLite store: what the service's routes keep."""

from __future__ import annotations

import json

import pytest

from tcms_daq.cli import main
from tcms_daq.compensation import Compensator
from tcms_daq.config import packaged_config_dir
from tcms_daq.discrepancy.model_file import DiscrepancyModel, ModelTerm
from tcms_daq.store import RunStore
from tcms_daq.store.compensation import CompensationRejected, CompensationVersions, UnknownVersion

GEOMETRY = packaged_config_dir() / "geometry-sim.toml"


@pytest.fixture
def versions(tmp_path):
    store = RunStore(tmp_path / "runs.sqlite", bench_id="b1", bench_name="b1")
    yield CompensationVersions(store)
    store.close()


def test_upload_show_history_rollback(versions):
    with pytest.raises(UnknownVersion, match="no compensation version yet"):
        versions.show()
    geometry = Compensator.from_geometry(GEOMETRY).to_toml()
    first = versions.upload(geometry, "the sim geometry")
    second = versions.upload(Compensator.identity().to_toml(), "none")
    assert [v.version for v in versions.history()] == [second.version, first.version]
    assert versions.show()[0] == second and versions.show(first.version)[1] == geometry
    back = versions.rollback(first.version)
    assert back.rollback_of == first.version and back.note == f"rollback to version {first.version}"
    assert versions.show()[1] == geometry
    with pytest.raises(UnknownVersion, match="no compensation version 99"):
        versions.rollback(99)


def test_an_unusable_compensator_is_not_kept(versions):
    with pytest.raises(CompensationRejected, match="^compensation: "):
        versions.upload("[compensator\n")
    with pytest.raises(CompensationRejected, match="note: at most 200"):
        versions.upload(Compensator.identity().to_toml(), "x" * 201)
    assert versions.history() == []


def test_apply_runs_first_and_its_toml_is_kept(versions):
    applied: list[str] = []

    def apply(text: str) -> str:
        applied.append(text)
        return Compensator.identity().to_toml()

    version = versions.upload("whatever the bench takes", "n", apply=apply)
    assert applied == ["whatever the bench takes"]
    assert versions.show(version.version)[1] == Compensator.identity().to_toml()


def test_from_model_moves_the_measuring_chain_effects(versions):
    with pytest.raises(CompensationRejected, match="no measuring-chain effect"):
        versions.from_model()
    model = DiscrepancyModel(terms=[ModelTerm("torsion_offset", {"coef_arcsec_per_nm": 0.004})])
    versions.store.add_bench_model(model.to_toml(), "found")
    done = versions.from_model()
    assert 'type = "torsion"' in versions.show()[1] and "from bench model version 1" in done.compensation.note
    assert done.bench_model.version == 2 and "moved torsion_offset" in done.bench_model.note


def test_the_command_line(tmp_path, capsys, monkeypatch):
    monkeypatch.delenv("TCMS_STORE_URL", raising=False)
    base = ["compensation", "--data-dir", str(tmp_path / "data")]
    assert main([*base, "list"]) == 2 and "no run store at" in capsys.readouterr().err
    assert main([*base, "upload", str(GEOMETRY), "--note", "sim geometry"]) == 0
    assert "compensation version 1: kept from" in capsys.readouterr().out
    path = tmp_path / "bad.toml"
    path.write_text("[compensator\n", encoding="utf-8")
    assert main([*base, "upload", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("tcms: error: compensation") and err.count("\n") == 1
    assert main([*base, "--json", "rollback", "1"]) == 0
    assert json.loads(capsys.readouterr().out)["rollback_of"] == 1
    assert main([*base, "--json", "list"]) == 0
    assert [v["version"] for v in json.loads(capsys.readouterr().out)] == [2, 1]
    assert main([*base, "show", "1"]) == 0
    assert capsys.readouterr().out == Compensator.from_geometry(GEOMETRY).to_toml()
    assert main([*base, "show", "7"]) == 2 and "no compensation version 7" in capsys.readouterr().err
    assert main([*base, "from-model"]) == 2 and "no measuring-chain effect" in capsys.readouterr().err

"""The compensator in the acquisition path of the default simulated bench (config/bench-sim.toml)."""

import json

import numpy as np
import pytest

from tcms_daq.cli import main
from tcms_daq.compensation import Compensator, load_geometry
from tcms_daq.compensation.geometry import evaluate_geometry


def run_json(capsys, *extra):
    assert main(["run", "--reducer", "RV-110E", "--json", *extra]) == 0
    return json.loads(capsys.readouterr().out)


def test_default_geometry_is_realistic(repo_root):
    # config/geometry-sim.toml: part errors of a few mrad / hundredths of a mm, not the paper's 5–18 mrad;
    # the encoder over-reads by ≈2.8 % (k = 0.972, like Table 4) plus a small positive torsion term
    geom = load_geometry(repo_root / "config" / "geometry-sim.toml")
    assert max(abs(p.dtau_rad) for p in geom.parts) <= 0.003
    model = evaluate_geometry(geom)
    assert 0.96 < model.k < 0.98
    assert 0 < model.delta_l_mm < 0.5


def test_run_is_compensated_and_raw_encoder_is_not(capsys):
    # Acceptance: with the default geometric errors the compensated run is within 1 % of the true rigidity,
    # while the raw encoder (--no-compensation) is off by more than 2 %. The raw encoder reads
    # (θ + c·T)/k with k = 0.972 and c = 0.00042″/N·m: for 294 N·m/arcmin (0.204″/N·m) that is 3 % more
    # angle per N·m, i.e. a rigidity ≈3 % low; the compensator (built from the same geometry file) undoes it.
    comp = run_json(capsys)
    raw = run_json(capsys, "--no-compensation")
    truth = comp["truth"]["rigidity_nm_per_arcmin"]
    assert truth == pytest.approx(294.0, rel=1e-3)
    assert abs(comp["rigidity_nm_per_arcmin"] / truth - 1) < 0.01
    assert abs(raw["rigidity_nm_per_arcmin"] / truth - 1) > 0.02
    assert raw["rigidity_nm_per_arcmin"] < truth  # over-reading encoder → too little stiffness
    assert comp["compensation"].endswith("geometry-sim.toml")
    assert "no-compensation" in raw["compensation"]


def test_sim_encoder_reads_through_the_forward_chain(repo_root):
    # the virtual bench's measuring-chain hook is the compensator's forward direction
    from tcms_daq.sim.bench import SimulatedBench

    from tcms_daq.config import load_bench_config

    cfg = load_bench_config(repo_root / "config" / "bench-sim.toml")
    bench = SimulatedBench.from_config(cfg)
    bench.set_drive_enabled(True)
    bench.set_torque_target(800.0, 4000.0)
    s = bench.advance(0.5)
    comp = Compensator.from_geometry(repo_root / "config" / "geometry-sim.toml")
    expected = comp.encoder_reading(s.extra["true_angle_arcsec"], s.extra["applied_torque_nm"])
    # the encoder adds noise (0.2″) and quantisation (0.1″) on top of the chain
    assert np.max(np.abs(s.angle_arcsec - expected)) < 1.5
    assert np.mean(s.angle_arcsec[-100:] - s.extra["true_angle_arcsec"][-100:]) > 3.0

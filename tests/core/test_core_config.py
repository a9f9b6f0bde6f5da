"""Configuration: the shipped files load; every invalid file names the file, the key and the problem."""

from __future__ import annotations

from pathlib import Path

import pytest

from tcms_daq.config import (
    BenchConfig,
    apply_overrides,
    get_reducer,
    hd_twist_arcsec,
    load_bench_config,
    load_reducer_catalogue,
    load_test_profile,
    packaged_config_dir,
)
from tcms_daq.errors import ConfigError
from tcms_daq.units import ARCSEC_PER_RAD


def test_catalogue_has_the_issue_values(catalogue):
    rv110 = catalogue["RV-110E"]
    assert (rv110.kind, rv110.rated_torque_nm, rv110.rigidity_nm_per_arcmin) == ("rv", 1078.0, 294.0)
    assert catalogue["RV-100C"].rigidity_nm_per_arcmin == 510.0
    assert catalogue["RV-60N"].rigidity_nm_per_arcmin == 200.0
    hd = catalogue["HFUC-32-100"]
    assert (hd.t1_nm, hd.t2_nm) == (29.0, 108.0)
    assert (hd.k1_nm_per_rad, hd.k2_nm_per_rad, hd.k3_nm_per_rad) == (6.7e4, 1.1e5, 1.2e5)
    for spec in catalogue.values():
        assert spec.sources, f"{spec.name} has no sources"
        assert spec.backlash_limit_arcsec > 0 and spec.lost_motion_limit_arcsec > 0
    assert "rated_torque_nm" in catalogue["RV-60N"].assumed


def test_hd_catalogue_curve_worked_example(catalogue):
    # HFUC-32-100 at 60 N·m: 29/6.7e4 + 31/1.1e5 = 7.15e-4 rad (Harmonic Drive manual)
    phi_rad = hd_twist_arcsec(60.0, catalogue["HFUC-32-100"]) / ARCSEC_PER_RAD
    assert phi_rad == pytest.approx(29 / 6.7e4 + 31 / 1.1e5, rel=1e-12)
    assert phi_rad == pytest.approx(7.15e-4, abs=0.005e-4)


def test_default_bench_config(bench_config):
    assert isinstance(bench_config, BenchConfig)
    assert bench_config.bench.max_torque_nm == 2000.0
    assert bench_config.instruments.angle.driver == "virtual"
    assert bench_config.sim.reducer == "RV-110E"
    assert bench_config.sim.effects == {}
    assert bench_config.resolve("geometry-sim.toml") == str(packaged_config_dir() / "geometry-sim.toml")


def _error(exc_info) -> str:
    msg = str(exc_info.value)
    assert "\n" not in msg
    return msg


def test_missing_key_names_file_key_problem(write, reducers_text):
    path = write("reducers.toml", reducers_text.replace("rated_torque_nm = 1078.0\n", "", 1))
    with pytest.raises(ConfigError) as exc:
        load_reducer_catalogue(path)
    msg = _error(exc)
    assert str(path) in msg and "reducers.RV-110E.rated_torque_nm" in msg and "missing key" in msg


def test_wrong_type_names_file_key_problem(write, reducers_text):
    path = write("reducers.toml", reducers_text.replace("rigidity_nm_per_arcmin = 294.0", 'rigidity_nm_per_arcmin = "stiff"'))
    with pytest.raises(ConfigError) as exc:
        load_reducer_catalogue(path)
    msg = _error(exc)
    assert str(path) in msg and "reducers.RV-110E.rigidity_nm_per_arcmin" in msg and "'stiff'" in msg


def test_negative_rigidity_is_rejected(write, reducers_text):
    path = write("reducers.toml", reducers_text.replace("rigidity_nm_per_arcmin = 510.0", "rigidity_nm_per_arcmin = -510.0"))
    with pytest.raises(ConfigError) as exc:
        load_reducer_catalogue(path)
    msg = _error(exc)
    assert str(path) in msg and "reducers.RV-100C.rigidity_nm_per_arcmin" in msg and "greater than 0" in msg


def test_harmonic_without_k3_and_bad_breakpoints(write, reducers_text):
    path = write("a.toml", reducers_text.replace("k3_nm_per_rad = 1.2e5\n", ""))
    with pytest.raises(ConfigError, match=r"reducers\.HFUC-32-100.*needs k3_nm_per_rad"):
        load_reducer_catalogue(path)
    path = write("b.toml", reducers_text.replace("t2_nm = 108.0", "t2_nm = 20.0"))
    with pytest.raises(ConfigError, match=r"t2_nm \(20.0\) must be greater than t1_nm"):
        load_reducer_catalogue(path)


def test_sources_must_name_fields(write, reducers_text):
    path = write("reducers.toml", reducers_text.replace('assumed = ["lost_motion_limit_arcsec", "ratio"]', 'assumed = ["stiffnes"]', 1))
    with pytest.raises(ConfigError, match=r"reducers\.RV-110E.*unknown field 'stiffnes'"):
        load_reducer_catalogue(path)


def test_unknown_reducer_lists_known_ones(catalogue):
    with pytest.raises(ConfigError) as exc:
        get_reducer(catalogue, "RV-999X", "config/reducers.toml")
    msg = _error(exc)
    assert "config/reducers.toml" in msg and "'RV-999X'" in msg and "RV-110E" in msg
    assert get_reducer(catalogue, "rv-110e").name == "RV-110E"


def test_invalid_toml_and_missing_file(write, tmp_path):
    path = write("broken.toml", "[sim\nseed = 1\n")
    with pytest.raises(ConfigError, match=r"broken\.toml: invalid TOML"):
        load_bench_config(path)
    with pytest.raises(ConfigError, match=r"nothere\.toml: no such file"):
        load_bench_config(tmp_path / "nothere.toml")


def test_bench_config_errors(write, bench_text):
    path = write("bench.toml", bench_text.replace("sample_rate_hz = 500.0", "sample_rate_hz = -5.0"))
    with pytest.raises(ConfigError) as exc:
        load_bench_config(path)
    msg = _error(exc)
    assert str(path) in msg and "sim.sample_rate_hz" in msg and "greater than 0" in msg and "-5.0" in msg

    path = write("bench2.toml", bench_text.replace("seed = 0", "seed = 0\nsede = 1"))
    with pytest.raises(ConfigError, match=r"sim\.sede: unknown key"):
        load_bench_config(path)

    path = write("bench3.toml", bench_text.replace('kind = "continuous"', 'kind = "wobbly"'))
    with pytest.raises(ConfigError, match=r"procedure\.kind: .*'wobbly'"):
        load_bench_config(path)

    path = write("bench4.toml", bench_text.replace("max_torque_nm = 2000.0", 'max_torque_nm = "lots"'))
    with pytest.raises(ConfigError, match=r"bench\.max_torque_nm: .*'lots'"):
        load_bench_config(path)


def test_every_table_is_declared(write, bench_text):
    """No table or key is kept unchecked: [service] and [simulators] are models; anything else is an error."""
    cfg = load_bench_config(write("bench.toml", bench_text + "\n[service]\napi_token = \"t0ken\"\n"
                                                          "[simulators]\nports = { nd287 = 0 }\n"))
    assert cfg.service.api_token == "t0ken" and cfg.simulators.settings() == {"ports": {"nd287": 0}}
    with pytest.raises(ConfigError, match=r"service\.port: unknown key"):
        load_bench_config(write("bench2.toml", bench_text + "\n[service]\nport = 8000\n"))
    with pytest.raises(ConfigError, match=r"servise: unknown key"):
        load_bench_config(write("bench3.toml", bench_text + "\n[servise]\napi_token = \"x\"\n"))


def test_missing_reducers_table(write):
    with pytest.raises(ConfigError, match=r"empty\.toml: reducers: missing key"):
        load_reducer_catalogue(write("empty.toml", "title = 'x'\n"))


def test_test_profile_validation():
    assert load_test_profile({"kind": "stepped", "step_nm": 25}).step_nm == 25
    with pytest.raises(ConfigError, match=r"<api>: cycles: .*greater than or equal to 1"):
        load_test_profile({"cycles": 0}, source="<api>")


def test_packaged_configs_are_found_by_name_from_any_directory(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    cfg = load_bench_config("bench-loopback.toml")
    assert Path(cfg.source_path) == packaged_config_dir() / "bench-loopback.toml"
    (tmp_path / "bench-loopback.toml").write_text((packaged_config_dir() / "bench-sim.toml").read_text())
    assert Path(load_bench_config("bench-loopback.toml").source_path) == Path("bench-loopback.toml")  # local first
    with pytest.raises(ConfigError, match=r"nope\.toml: no such file \(packaged configs, usable by name: .*bench-sim"):
        load_bench_config("nope.toml")
    with pytest.raises(ConfigError, match="no such file"):
        load_bench_config("sub/bench-sim.toml")  # a path with a folder is never taken for a packaged name


def test_overrides_change_a_copy_before_validation():
    cfg = load_bench_config("bench-loopback.toml", overrides=[
        "instruments.angle.url=socket://127.0.0.1:5001", "bench.max_torque_nm=900", 'bench.name="port 5001"'])
    assert cfg.instruments.angle.url == "socket://127.0.0.1:5001"
    assert cfg.bench.max_torque_nm == 900.0 and cfg.bench.name == "port 5001"
    assert load_bench_config("bench-loopback.toml").instruments.angle.url != "socket://127.0.0.1:5001"
    with pytest.raises(ConfigError, match="bench.max_torque_nm: .*-5"):
        load_bench_config("bench-loopback.toml", overrides=["bench.max_torque_nm=-5"])
    with pytest.raises(ConfigError, match="expected dotted.key=VALUE"):
        apply_overrides({}, ["no-equals-sign"])
    with pytest.raises(ConfigError, match="bench.name is not a table"):
        apply_overrides({"bench": {"name": "x"}}, ["bench.name.deeper=1"])


def test_loader_watchdog_fields_are_typed_with_safe_defaults():
    """[instruments.loader]: the drive's communication watchdog is on by default (<= 1 s of silence) and its fields
    are checked at the boundary, against the loader driver's options model (no coercion, no out-of-range
    reaction); a key the driver does not take is refused."""
    from pydantic import ValidationError

    from tcms_daq.config.models import InstrumentsConfig

    modbus = InstrumentsConfig.model_validate({"loader": {"driver": "cia402-modbus", "url": "tcp://127.0.0.1:1"}})
    assert 0 < modbus.loader.options.comm_timeout_ms <= 1000 and modbus.loader.options.abort_connection_option == 1
    canopen = InstrumentsConfig.model_validate({"loader": {"driver": "cia402-canopen", "url": "virtual://x"}})
    assert 0 < canopen.loader.options.consumer_timeout_ms <= 1000
    for driver, bad in (("cia402-modbus", {"comm_timeout_ms": "500"}), ("cia402-modbus", {"comm_timeout_ms": -1}),
                        ("cia402-modbus", {"abort_connection_option": 0}),
                        ("cia402-canopen", {"master_heartbeat_ms": 5}),
                        ("cia402-canopen", {"comm_timeout_ms": 1000}),  # a Modbus key on a CANopen drive
                        ("virtual", {"master_heartbeat_ms": 100})):
        with pytest.raises(ValidationError, match=f"driver '{driver}'"):
            InstrumentsConfig.model_validate({"loader": {"driver": driver, "url": "virtual://x", **bad}})


def test_instrument_options_unknown_key_names_instrument_key_and_allowed(write, bench_text):
    """An instrument option the driver does not take fails when the file is read: the error names the instrument,
    the key and the keys its driver takes."""
    path = write("bench.toml", bench_text)
    with pytest.raises(ConfigError) as err:
        load_bench_config(path, ["instruments.angle.urll=x"])
    text = str(err.value)
    assert "instruments.angle:" in text and "'urll'" in text
    assert "its options: acceleration_deg_per_s2, max_torque_nm, max_velocity_deg_per_s, rated_torque_nm, url)" in text
    with pytest.raises(ConfigError, match=r"instruments\.torque: unknown driver 'nope' \(known: .*nd287"):
        load_bench_config(path, ["instruments.torque.driver=nope"])
    with pytest.raises(ConfigError, match=r"instruments\.loader: driver 'cia402-canopen' option 'node_id': .*"
                                          r"less than or equal to 127 \(got 300\)"):
        load_bench_config(path, ["instruments.loader.driver=cia402-canopen", "instruments.loader.node_id=300"])

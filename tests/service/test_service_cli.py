"""``tcms serve`` argument and config errors are one line and exit code 2 (before any server starts)."""

from __future__ import annotations

from tcms_daq.cli import main


def test_bad_arguments_and_configs_are_one_line_errors(tmp_path, capsys):
    assert main(["serve", "--sim-speed", "0", "--data-dir", str(tmp_path)]) == 2
    assert capsys.readouterr().err.strip() == "tcms: error: --sim-speed must be a positive number, got 0.0"
    assert main(["serve", "--port", "70000", "--data-dir", str(tmp_path)]) == 2
    assert "--port must be 0…65535" in capsys.readouterr().err
    missing = tmp_path / "nope.toml"
    assert main(["serve", "--config", str(missing), "--data-dir", str(tmp_path)]) == 2
    assert capsys.readouterr().err.strip() == f"tcms: error: {missing}: no such file"
    bad = tmp_path / "bad.toml"
    bad.write_text("[bench]\nmax_torque_nm = -1\n", encoding="utf-8")
    assert main(["serve", "--config", str(bad), "--data-dir", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("tcms: error: ") and "max_torque_nm" in err and "\n" not in err
    not_a_dir = tmp_path / "file"
    not_a_dir.write_text("x", encoding="utf-8")
    assert main(["serve", "--data-dir", str(not_a_dir), "--port", "0"]) == 2
    assert capsys.readouterr().err.strip() == (f"tcms: error: run store {not_a_dir}/tcms-runs.sqlite3: cannot open "
                                               "it (File exists); choose another --data-dir")
    broken = tmp_path / "broken"
    broken.mkdir()
    (broken / "tcms-runs.sqlite3").write_bytes(b"not a database at all" * 10)
    assert main(["serve", "--data-dir", str(broken), "--port", "0"]) == 2
    assert "(file is not a database)" in capsys.readouterr().err


def test_an_instrument_that_does_not_answer_is_a_one_line_error_before_the_banner(tmp_path, capsys):
    import socket
    import tomllib

    import tomli_w

    from tcms_daq.config.loader import default_bench_config_path

    closed = socket.socket()
    closed.bind(("127.0.0.1", 0))  # bound, never listening: connections are refused
    port = closed.getsockname()[1]
    config_dir = default_bench_config_path().parent
    data = tomllib.loads((config_dir / "bench-compose.toml").read_text(encoding="utf-8"))
    data["instruments"]["angle"]["url"] = f"socket://127.0.0.1:{port}"
    for key in ("reducers", "compensation"):
        data["bench"][key] = str(config_dir / data["bench"][key])
    cfg = tmp_path / "bench.toml"
    cfg.write_text(tomli_w.dumps(data), encoding="utf-8")
    try:
        assert main(["serve", "--config", str(cfg), "--port", "0", "--data-dir", str(tmp_path / "d")]) == 2
    finally:
        closed.close()
    out, err = capsys.readouterr()
    assert out == "" and err.startswith(f"tcms: error: ND 287: cannot open socket://127.0.0.1:{port}")
    assert err.count("\n") == 1

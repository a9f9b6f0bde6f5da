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

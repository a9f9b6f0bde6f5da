"""`tcms sim serve` command-line errors: one line, exit code 2, nothing left running."""

from __future__ import annotations

import socket

from tcms_daq.cli import main


def test_port_in_use_is_a_one_line_error(capsys):
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        code = main(["sim", "serve", "--nd287-port", str(port), "--aed-port", "0", "--modbus-port", "0",
                     "--socketcand-port", "0", "--duration", "0"])
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert err.startswith("tcms: error: cannot start the simulators") and "\n" not in err


def test_bad_options(capsys):
    assert main(["sim", "serve", "--speed", "0"]) == 2
    assert "--speed must be > 0" in capsys.readouterr().err
    assert main(["sim", "serve", "--aed-port", "70000"]) == 2
    assert "--aed-port" in capsys.readouterr().err


def test_free_ports_and_a_urls_file_that_run_check_and_serve_read(tmp_path, capsys):
    """`--free-ports --urls-file F` writes the JSON line to F (removed at exit); `--sim-urls F` maps each of a
    config's instruments to the simulator of its driver, before the user's --set (which still wins)."""
    import argparse
    import json

    from tcms_daq.cli.options import apply_sim_urls

    urls_file = tmp_path / "sim.json"
    assert main(["sim", "serve", "--free-ports", "--urls-file", str(urls_file), "--duration", "0"]) == 0
    line = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert not urls_file.exists(), "the file of simulators that ended is removed"
    assert set(line["ports"]) == {"nd287", "aed", "modbus", "socketcand"}
    assert all(p not in (4001, 4002, 5020, 29536) for p in line["ports"].values())
    assert line["drivers"]["cia402-modbus"] == line["urls"]["loader_modbus"]

    urls_file.write_text(json.dumps(line))
    args = argparse.Namespace(config="bench-loopback-modbus.toml", sim_urls=str(urls_file),
                              overrides=["instruments.angle.url=socket://127.0.0.1:1"])
    apply_sim_urls(args)
    assert args.overrides == [f"instruments.angle.url={line['urls']['angle']}",
                              f"instruments.torque.url={line['urls']['torque']}",
                              f"instruments.loader.url={line['urls']['loader_modbus']}",
                              "instruments.angle.url=socket://127.0.0.1:1"]


def test_sim_urls_errors_are_one_line(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr("tcms_daq.cli.options.SIM_URLS_WAIT_S", 0.2)
    missing = tmp_path / "none.json"
    assert main(["check", "--config", "bench-loopback.toml", "--sim-urls", str(missing)]) == 2
    err = capsys.readouterr().err.strip()
    assert "no such file after" in err and "--urls-file" in err and "\n" not in err
    (tmp_path / "bad.json").write_text("{}")
    assert main(["check", "--config", "bench-loopback.toml", "--sim-urls", str(tmp_path / "bad.json")]) == 2
    assert "not a file `tcms sim serve --urls-file` wrote" in capsys.readouterr().err

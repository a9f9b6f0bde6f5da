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

"""Command-line options shared by several commands (the bench config of run, serve, sim serve; the decision rule)."""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path
from typing import Any

from tcms_daq.errors import ConfigError

SIM_URLS_WAIT_S = 30.0  # how long --sim-urls waits for simulators started a moment ago to write their file


def add_bench_config_options(parser: argparse.ArgumentParser, sim_urls: bool = True) -> None:
    """``--config FILE`` (a path, or the name of a packaged config), repeatable ``--set KEY=VALUE`` and (unless
    ``sim_urls`` is False) ``--sim-urls FILE``, the instruments' URLs from ``tcms sim serve --urls-file FILE``."""
    parser.add_argument("--config", default=None, metavar="FILE",
                        help="bench config TOML: a path, or a packaged config by name (bench-sim.toml, "
                        "bench-loopback.toml, bench-loopback-modbus.toml, bench-compose.toml); default bench-sim.toml")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                        help="override one config value (TOML syntax; repeatable), e.g. "
                        "--set instruments.angle.url=socket://127.0.0.1:5001")
    if sim_urls:
        parser.add_argument("--sim-urls", metavar="FILE", default=None,
                            help="each instrument's URL from the file `tcms sim serve --urls-file FILE` writes (the "
                            "simulators on free ports), by the instrument's driver; waits up to "
                            f"{SIM_URLS_WAIT_S:g} s for the file; --set still wins")


def apply_sim_urls(args: argparse.Namespace) -> None:
    """Turn ``--sim-urls FILE`` into ``instruments.<name>.url=…`` overrides placed before the user's ``--set``."""
    path = getattr(args, "sim_urls", None)
    if path is None:
        return
    from tcms_daq.config.loader import default_bench_config_path, read_toml, resolve_config_path

    config = resolve_config_path(args.config) if args.config is not None else default_bench_config_path()
    by_driver = read_sim_urls(Path(path))
    instruments = read_toml(config).get("instruments", {})
    # a second instrument of one driver (the input torque AED) is served at its own URL: "<driver>@<kind>"
    found = [f"instruments.{name}.url={by_driver.get(section['driver'] + '@' + name) or by_driver[section['driver']]}"
             for name, section in instruments.items()
             if isinstance(section, dict) and section.get("driver") in by_driver]
    if not found:
        raise ConfigError(f"--sim-urls {path}: none of {config.name}'s instruments is served by those simulators "
                          f"(they serve {', '.join(sorted(by_driver))})")
    args.overrides = [*found, *args.overrides]


def read_sim_urls(path: Path, wait_s: float | None = None) -> dict[str, str]:
    """The driver -> URL table of a ``tcms sim serve --urls-file`` file, waiting up to ``wait_s`` (default
    SIM_URLS_WAIT_S) for it to appear (the simulators may have been started in the background a moment ago)."""
    wait_s = SIM_URLS_WAIT_S if wait_s is None else wait_s
    deadline = time.monotonic() + wait_s
    while not path.is_file():
        if time.monotonic() >= deadline:
            raise ConfigError(f"--sim-urls {path}: no such file after {wait_s:g} s (start the simulators with "
                              f"`tcms sim serve --free-ports --urls-file {path}` first)")
        time.sleep(0.1)
    try:
        doc: Any = json.loads(path.read_text(encoding="utf-8"))
        drivers = doc["drivers"]
        if not isinstance(drivers, dict) or not all(isinstance(v, str) for v in drivers.values()):
            raise TypeError
    except (OSError, ValueError, KeyError, TypeError):
        raise ConfigError(f"--sim-urls {path}: not a file `tcms sim serve --urls-file` wrote") from None
    return dict(drivers)


def write_sim_urls(path: Path, info: dict[str, Any]) -> None:
    """Write the simulators' JSON line to ``path`` at once (a reader never sees half a file)."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(json.dumps(info) + "\n", encoding="utf-8")
    os.replace(tmp, path)


def add_decision_rule_option(parser: argparse.ArgumentParser, default: str | None = "guarded") -> None:
    """``--decision-rule simple|guarded``: the ISO 14253-1 rule of the pass/fail decision."""
    shown = "the bench config's [bench] decision_rule" if default is None else default
    parser.add_argument("--decision-rule", choices=("simple", "guarded"), default=default,
                        help="ISO 14253-1 decision: 'guarded' (pass only inside a limit by U, fail only outside "
                        "by U, otherwise undecided) or 'simple' acceptance (the value alone); default " + shown)

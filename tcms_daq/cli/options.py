"""Command-line options shared by the commands that compose a bench (run, serve, sim serve)."""

from __future__ import annotations

import argparse


def add_bench_config_options(parser: argparse.ArgumentParser) -> None:
    """``--config FILE`` (a path, or the name of a packaged config) and repeatable ``--set KEY=VALUE``."""
    parser.add_argument("--config", default=None, metavar="FILE",
                        help="bench config TOML: a path, or a packaged config by name (bench-sim.toml, "
                        "bench-loopback.toml, bench-loopback-modbus.toml, bench-compose.toml); default bench-sim.toml")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                        help="override one config value (TOML syntax; repeatable), e.g. "
                        "--set instruments.angle.url=socket://127.0.0.1:5001")

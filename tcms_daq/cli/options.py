"""Command-line options shared by several commands (the bench config of run, serve, sim serve; the decision rule)."""

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


def add_decision_rule_option(parser: argparse.ArgumentParser, default: str | None = "guarded") -> None:
    """``--decision-rule simple|guarded``: the ISO 14253-1 rule of the pass/fail decision."""
    shown = "the bench config's [bench] decision_rule" if default is None else default
    parser.add_argument("--decision-rule", choices=("simple", "guarded"), default=default,
                        help="ISO 14253-1 decision: 'guarded' (pass only inside a limit by U, fail only outside "
                        "by U, otherwise undecided) or 'simple' acceptance (the value alone); default " + shown)

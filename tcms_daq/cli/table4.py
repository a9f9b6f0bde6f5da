"""``tcms table4 [--json | --markdown] [--geometry PATH]``: the paper's Table 4 comparison (docs/table4.md)."""

from __future__ import annotations

import argparse
import json

from tcms_daq.compensation.table4 import format_table4, render_markdown, table4_comparison
from tcms_daq.config import resolve_config_path


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "table4",
        help="reproduce the comparison with the paper's Table 4",
        description="Raw encoder error, the paper's compensated column, the geometric model's prediction from "
        "Tables 2-3 and our calibrated fits with held-out error, on the paper's Table 4.",
    )
    p.add_argument("--geometry", help="geometry TOML: a path or a packaged name (default geometry-paper.toml)")
    fmt = p.add_mutually_exclusive_group()
    fmt.add_argument("--json", action="store_true", help="print JSON")
    fmt.add_argument("--markdown", action="store_true", help="print the documentation page (docs/table4.md)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    result = table4_comparison(None if args.geometry is None else resolve_config_path(args.geometry))
    if args.json:
        print(json.dumps(result, indent=2))
    elif args.markdown:
        print(render_markdown(result), end="")
    else:
        print(format_table4(result))
    return 0

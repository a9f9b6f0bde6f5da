"""Run every benchmark module and write ``benchmarks/results.json`` plus ``benchmarks/results.md``.

Usage: ``python -m benchmarks [--quick] [--only NAME ...] [--out DIR]``. Each module reports metrics measured
in one run, as ratios to a baseline measured in the same run where a target is a time.
"""

from __future__ import annotations

import argparse
import importlib
import json
import pkgutil
import platform
import sys
import time
import traceback
from pathlib import Path

import benchmarks

HERE = Path(__file__).resolve().parent


def discover() -> list[str]:
    return sorted(m.name for m in pkgutil.iter_modules(benchmarks.__path__) if not m.name.startswith("_"))


def _fmt(value) -> str:
    if isinstance(value, float):
        return f"{value:.4g}"
    return str(value)


def to_markdown(results: list[dict]) -> str:
    lines = ["| benchmark | metric | value | target | met |", "|---|---|---|---|---|"]
    for res in results:
        name = res.get("name", "?")
        if "error" in res:
            lines.append(f"| {name} | error | {res['error']} | | no |")
            continue
        targets = res.get("targets", {})
        for key, value in res.get("metrics", {}).items():
            t = targets.get(key)
            limit = _fmt(t["limit"]) if t else ""
            met = ("yes" if t["met"] else "**no**") if t else ""
            lines.append(f"| {name} | {key} | {_fmt(value)} | {limit} | {met} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks", description=__doc__)
    parser.add_argument("--quick", action="store_true", help="shorter runs (smoke test of the benchmarks)")
    parser.add_argument("--only", nargs="*", default=None, help="benchmark module names to run")
    parser.add_argument("--out", type=Path, default=HERE, help="directory for results.json and results.md")
    args = parser.parse_args(argv)
    names = args.only or discover()
    results = []
    for name in names:
        started = time.perf_counter()
        print(f"[benchmarks] {name} …", file=sys.stderr, flush=True)
        try:
            res = importlib.import_module(f"benchmarks.{name}").run(quick=args.quick)
        except Exception as exc:  # a failing benchmark is reported, not fatal for the others
            traceback.print_exc()
            res = {"name": name, "error": f"{type(exc).__name__}: {exc}"}
        res.setdefault("name", name)
        res["duration_s"] = round(time.perf_counter() - started, 2)
        results.append(res)
    doc = {
        "machine": {"python": platform.python_version(), "platform": platform.platform(), "processor": platform.processor()},
        "quick": args.quick,
        "results": results,
    }
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "results.json").write_text(json.dumps(doc, indent=2, default=float) + "\n")
    table = to_markdown(results)
    (args.out / "results.md").write_text(table)
    print(table)
    return 1 if any("error" in r for r in results) else 0


if __name__ == "__main__":
    sys.exit(main())

"""Run the benchmark modules and write ``benchmarks/results.json`` plus ``benchmarks/results.md``; rewrite the
README's performance table from results.json.

Usage: ``python -m benchmarks [--quick] [--only NAME ...] [--out DIR]`` measures;
``python -m benchmarks --readme`` rewrites README.md's performance table from results.json and measures nothing.

Each module reports figures measured in several runs as min/median/max (``benchmarks/_runs.py``), as ratios to a
baseline measured in the same run where a target is a time. The harness records for each module when it was
measured, the machine's 1-minute load average before and after, and whether it was a quick run. With ``--only``
the other modules' results already in results.json are kept.
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import pkgutil
import platform
import sys
import time
import traceback
from pathlib import Path

import benchmarks
from benchmarks._report import (
    PLANT_BEGIN,
    PLANT_END,
    plant_scale_table,
    readme_table,
    replace_readme_table,
    to_markdown,
)

HERE = Path(__file__).resolve().parent
README = HERE.parent / "README.md"


def discover() -> list[str]:
    return sorted(m.name for m in pkgutil.iter_modules(benchmarks.__path__) if not m.name.startswith("_"))


def _load_results(path: Path) -> list[dict]:
    if not path.exists():
        return []
    return list(json.loads(path.read_text(encoding="utf-8")).get("results", []))


def _measure(name: str, quick: bool) -> dict:
    load_before = os.getloadavg()[0]
    started_at, started = time.time(), time.perf_counter()
    print(f"[benchmarks] {name} …", file=sys.stderr, flush=True)
    try:
        res = importlib.import_module(f"benchmarks.{name}").run(quick=quick)
    except Exception as exc:  # a failing benchmark is reported, not fatal for the others
        traceback.print_exc()
        res = {"name": name, "error": f"{type(exc).__name__}: {exc}"}
    res.setdefault("name", name)
    res["measured_at"] = started_at
    res["duration_s"] = round(time.perf_counter() - started, 2)
    res["quick"] = quick
    res["load_average_1min"] = {"before": load_before, "after": os.getloadavg()[0], "cpus": os.cpu_count()}
    return res


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="shorter runs (smoke test of the benchmarks)")
    parser.add_argument("--only", nargs="*", default=None, help="benchmark module names to run")
    parser.add_argument("--out", type=Path, default=HERE, help="directory for results.json and results.md")
    parser.add_argument("--readme", action="store_true",
                        help="rewrite README.md's performance table from results.json (measures nothing)")
    args = parser.parse_args(argv)
    results_path = args.out / "results.json"
    if args.readme:
        results = _load_results(results_path)
        text = replace_readme_table(README.read_text(encoding="utf-8"), readme_table(results))
        text = replace_readme_table(text, plant_scale_table(results), (PLANT_BEGIN, PLANT_END))
        README.write_text(text, encoding="utf-8")
        print(f"README.md: performance and plant_scale tables rewritten from {results_path}")
        return 0
    names = args.only or discover()
    unknown = sorted(set(names) - set(discover()))
    if unknown:
        parser.error(f"unknown benchmark {unknown[0]!r} (known: {', '.join(discover())})")
    fresh = [_measure(name, args.quick) for name in names]
    kept = [r for r in _load_results(results_path) if r.get("name") not in names and r.get("name") in discover()]
    results = sorted(kept + fresh, key=lambda r: discover().index(r["name"]))
    doc = {
        "machine": {"python": platform.python_version(), "platform": platform.platform(),
                    "processor": platform.processor(), "cpus": os.cpu_count()},
        "results": results,
    }
    args.out.mkdir(parents=True, exist_ok=True)
    results_path.write_text(json.dumps(doc, indent=2, default=float) + "\n", encoding="utf-8")
    report = to_markdown(results)
    (args.out / "results.md").write_text(
        "# Benchmark results\n\nWritten by `python -m benchmarks` (every metric; the README's table is "
        "`python -m benchmarks --readme`).\n\n" + report, encoding="utf-8")
    print(to_markdown(fresh))
    return 1 if any("error" in r for r in fresh) else 0


if __name__ == "__main__":
    sys.exit(main())

"""``python -m benchmarks.coverage [--runs N] [--seed S] [--only FAMILY …]``: the per-family coverage table."""

from __future__ import annotations

import argparse
import sys
import time

from benchmarks.coverage import RUNS, SEED, SHORT, declared_chain, markdown_table, run_family
from benchmarks.coverage.families import FAMILIES


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.coverage", description=__doc__)
    parser.add_argument("--runs", type=int, default=RUNS, help=f"runs per family (default {RUNS})")
    parser.add_argument("--seed", type=int, default=SEED)
    parser.add_argument("--only", nargs="*", default=None, help="family names")
    args = parser.parse_args(argv)
    names = {f.name for f in FAMILIES}
    unknown = sorted(set(args.only or ()) - names)
    if unknown:
        parser.error(f"unknown family {unknown[0]!r} (known: {', '.join(sorted(names))})")
    chain = declared_chain()
    results = []
    for family in FAMILIES:
        if args.only and family.name not in args.only:
            continue
        started = time.perf_counter()
        res = run_family(family, args.runs, args.seed, chain)
        print(f"[coverage] {family.name}: {family.describe()} — {args.runs} runs in "
              f"{time.perf_counter() - started:.0f} s, {len(res.failed)} not evaluated", file=sys.stderr, flush=True)
        beyond = "; ".join(f"{SHORT[q]} sd {s['beyond_chain_sd_over_U']:.3f} U, max {s['beyond_chain_max_over_U']:.2f} U"
                           for q, s in res.summary().items())
        print(f"    error beyond the chain's gain errors: {beyond}", file=sys.stderr, flush=True)
        for msg in res.failed[:3]:
            print(f"    {msg}", file=sys.stderr)
        results.append(res)
    print(markdown_table(results))
    return 0


if __name__ == "__main__":
    sys.exit(main())

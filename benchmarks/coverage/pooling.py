"""The trade of the Type A rule (``tcms_daq.uncertainty.budget.pooled_type_a``) in a model: a result's error has
λ times the variance the noise explains (λ > 1: the loops vary beyond the noise, which the bootstrap cannot see);
the noise bootstrap estimates the noise's variance with 7 degrees of freedom, the loop scatter the whole with
n − 1. Coverage of U = t(dof)·u for: the larger of the two (the rule before 2026-11-29), always pooled, and pooled
unless the F-test says the loops scatter more, at two levels.

``python -m benchmarks.coverage.pooling [--draws N] [--loops-dof D]`` prints the table of docs/uncertainty.md."""

from __future__ import annotations

import argparse
import sys

import numpy as np
from scipy.stats import t as student_t

from tcms_daq.uncertainty.budget import BOOTSTRAP_DRAWS, POOLING_LEVEL, pooled_type_a

LAMBDAS = (1.0, 2.0, 4.0, 8.0)
RULES = (("larger of the two", None), ("always pooled", 0.0), ("F-test at 0.05", 0.05),
         (f"F-test at {POOLING_LEVEL:g} (used)", POOLING_LEVEL))


def coverage(lam: float, level: float | None, dof_loops: int, draws: int, seed: int = 1) -> float:
    """Share of draws whose error lies within U under the rule (``level`` None: the larger of the two)."""
    rng = np.random.default_rng(seed)
    dof_noise = BOOTSTRAP_DRAWS - 1
    error = np.sqrt(lam) * rng.standard_normal(draws)
    u_noise = np.sqrt(rng.chisquare(dof_noise, draws) / dof_noise)
    u_loops = np.sqrt(lam * rng.chisquare(dof_loops, draws) / dof_loops)
    if level is None:
        u, dof = np.maximum(u_loops, u_noise), np.where(u_loops > u_noise, dof_loops, dof_noise)
    else:
        u, dof, _ = pooled_type_a(u_loops, dof_loops, u_noise, dof_noise, level)
    return float(np.mean(np.abs(error) <= student_t.ppf(0.975, dof) * u))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.coverage.pooling", description=__doc__)
    parser.add_argument("--draws", type=int, default=200_000)
    parser.add_argument("--loops-dof", type=int, default=2, help="n − 1 of the loops (default 2: three loops)")
    args = parser.parse_args(argv)
    print("| λ (loop variance / noise variance) | " + " | ".join(name for name, _ in RULES) + " |")
    print("|---|" + "---|" * len(RULES))
    for lam in LAMBDAS:
        cells = [f"{100 * coverage(lam, level, args.loops_dof, args.draws):.1f} %" for _, level in RULES]
        print(f"| {lam:g} | " + " | ".join(cells) + " |")
    larger, loops_larger = larger_of_two(args.loops_dof, args.draws)
    print(f"\nλ = 1: the larger of the two is on average {larger:.3f} × the true u (the loops are the larger in "
          f"{100 * loops_larger:.0f} % of the draws)")
    return 0


def larger_of_two(dof_loops: int, draws: int, seed: int = 1) -> tuple[float, float]:
    """With the loops varying by the noise only: the mean of max(u_loops, u_noise) in units of the true u, and the
    share of draws whose loop scatter is the larger."""
    rng = np.random.default_rng(seed)
    dof_noise = BOOTSTRAP_DRAWS - 1
    u_noise = np.sqrt(rng.chisquare(dof_noise, draws) / dof_noise)
    u_loops = np.sqrt(rng.chisquare(dof_loops, draws) / dof_loops)
    return float(np.mean(np.maximum(u_loops, u_noise))), float(np.mean(u_loops > u_noise))


if __name__ == "__main__":
    sys.exit(main())
